"""Stage b: ratio-test matching and RANSAC homographies with planted outliers."""

import numpy as np
import pytest

from pose.features.matching import (
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


# The loops the vectorised functions replaced, kept as their readable specification: the fast
# versions must give the very same matches (the benchmark figures were measured with these).
def _ratio_match_reference(query, train, ratio):
    sim = query @ train.T
    best2 = np.argpartition(-sim, 1, axis=1)[:, :2]
    s = np.take_along_axis(sim, best2, axis=1)
    order = np.argsort(-s, axis=1)
    best2, s = np.take_along_axis(best2, order, axis=1), np.take_along_axis(s, order, axis=1)
    d1, d2 = (np.sqrt(np.maximum(2 - 2 * s[:, j], 0)) for j in (0, 1))
    ok = d1 < ratio * d2
    return np.c_[np.nonzero(ok)[0], best2[ok, 0]]


def _ratio_test_3d_reference(idx, dist, points, ratio, merge_radius):
    q, m = [], []
    for i, (row, d) in enumerate(zip(idx, dist, strict=True)):
        if row[0] < 0 or not np.isfinite(points[row[0]]).all():
            continue
        others = points[row[row >= 0]]
        far = ~(np.linalg.norm(others - points[row[0]], axis=1) <= merge_radius)
        second = d[: len(far)][far]
        if len(second) == 0 or d[0] < ratio * second[0]:
            q.append(i)
            m.append(row[0])
    return np.array(q, int), np.array(m, int)


@pytest.mark.parametrize("seed", range(5))
def test_vectorised_ratio_tests_match_their_loops_exactly(seed):
    from pose.features.matching import ratio_test_3d

    rng = np.random.default_rng(seed)

    def unit(n):
        d = rng.normal(size=(n, 16))
        return (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)

    train = unit(60)
    query = np.r_[unit(80), train[:20] + rng.normal(0, 0.05, (20, 16)).astype(np.float32)]
    query[-1] = query[-2]  # a repeated query
    train[-1] = train[-2]  # a tie for the nearest (fails the test whichever comes first)
    for ratio in (0.7, 0.85, 1.0):
        np.testing.assert_array_equal(ratio_match(query, train, ratio),
                                      _ratio_match_reference(query, train, ratio))  # fmt: skip
    # 3-D test: points with unknowns (NaN), FLANN misses (-1, last in a row), near duplicates
    points = rng.uniform(-0.05, 0.05, (40, 3))
    points[rng.choice(40, 6, replace=False)] = np.nan
    points[1] = points[0] + 0.001
    idx = rng.integers(0, 40, (300, 5))
    misses = rng.integers(0, 6, 300)  # how many of each row's last neighbours FLANN missed
    dist = np.sort(rng.uniform(0.05, 0.5, (300, 5)), axis=1)
    for i, k in enumerate(misses):
        if k:
            idx[i, 5 - k :], dist[i, 5 - k :] = -1, np.inf
    idx[:20, :2] = [0, 1]  # the same place twice
    for ratio, radius in ((0.8, 0.004), (0.9, 0.02), (1.0, 0.0)):
        got = ratio_test_3d(idx, dist, points, ratio, radius)
        want = _ratio_test_3d_reference(idx, dist, points, ratio, radius)
        assert len(want[0]) > 10
        for g, w in zip(got, want, strict=True):
            np.testing.assert_array_equal(g, w)
            assert g.dtype == w.dtype
