"""Stage b: ratio-test matching and RANSAC homographies with planted outliers."""

import numpy as np
import pytest

from pose.matching import (
    DescriptorIndex,
    apply_homography,
    local_similarity,
    ransac_homography,
    ratio_match,
)


def _similarity(angle, scale, tx, ty):
    c, s = scale * np.cos(angle), scale * np.sin(angle)
    return np.array([[c, -s, tx], [s, c, ty], [0, 0, 1.0]])


@pytest.mark.parametrize("method", ["ransac", "magsac"])
def test_ransac_recovers_a_known_homography_despite_outliers(method):
    rng = np.random.default_rng(0)
    H = np.array([[0.9, -0.2, 30.0], [0.25, 1.1, -12.0], [1e-4, -2e-4, 1.0]])
    src = rng.uniform(0, 300, (120, 2))
    dst = apply_homography(H, src) + rng.normal(0, 0.3, (120, 2))
    bad = rng.choice(120, 40, replace=False)  # a third are outliers
    dst[bad] = rng.uniform(0, 300, (40, 2))
    H_est, inl = ransac_homography(src, dst, method=method, threshold=3.0, seed=1)
    assert H_est is not None
    truth = np.ones(120, bool)
    truth[bad] = False
    assert np.mean(inl == truth) > 0.97
    grid = rng.uniform(0, 300, (50, 2))
    err = np.linalg.norm(
        apply_homography(H_est / H_est[2, 2], grid) - apply_homography(H, grid), axis=1
    )
    assert err.max() < 1.5


def test_ransac_is_seeded():
    rng = np.random.default_rng(1)
    src = rng.uniform(0, 200, (60, 2))
    dst = rng.uniform(0, 200, (60, 2))  # pure noise: the answer depends on the sampling
    a = ransac_homography(src, dst, seed=5)
    b = ransac_homography(src, dst, seed=5)
    assert (a[0] is None) == (b[0] is None)
    np.testing.assert_array_equal(a[1], b[1])


def test_ransac_needs_four_points_and_a_known_method():
    H, inl = ransac_homography(np.zeros((3, 2)), np.zeros((3, 2)))
    assert H is None and not inl.any()
    with pytest.raises(ValueError, match="valid: \\['magsac', 'ransac'\\]"):
        ransac_homography(np.zeros((5, 2)), np.zeros((5, 2)), method="lmeds")


def test_local_similarity_reads_angle_and_scale():
    H = _similarity(np.radians(23.0), 1.3, 40, -7)
    angle, scale = local_similarity(H, np.array([100.0, 50.0]))
    assert np.degrees(angle) == pytest.approx(23.0, abs=1e-9)
    assert scale == pytest.approx(1.3, abs=1e-9)


def test_ratio_match_keeps_distinct_nearest_neighbours():
    rng = np.random.default_rng(2)
    train = rng.normal(size=(50, 128))
    train /= np.linalg.norm(train, axis=1, keepdims=True)
    query = train[[4, 9, 17]] + rng.normal(0, 0.01, (3, 128))
    query /= np.linalg.norm(query, axis=1, keepdims=True)
    ambiguous = (train[20] + train[21]) / np.linalg.norm(train[20] + train[21])
    pairs = ratio_match(np.vstack([query, ambiguous]), train, ratio=0.8)
    assert pairs.tolist() == [[0, 4], [1, 9], [2, 17]]


def test_descriptor_index_votes_for_the_view_that_shares_features():
    rng = np.random.default_rng(3)
    desc = rng.normal(size=(300, 128)).astype(np.float32)
    desc /= np.linalg.norm(desc, axis=1, keepdims=True)
    views = np.repeat(np.arange(3), 100)
    index = DescriptorIndex(desc, views, 3, seed=0)
    votes = index.vote(desc[100:140] + 0.01, k=2)
    assert np.argmax(votes) == 1 and votes[1] == 40
