"""Keypoint heading, visual words, the normalised RBF and occlusion augmentation (fast)."""

import cv2
import numpy as np
import pytest

from pose.features.keypoints import extract_sift
from pose.manifold.augment import occlude_features
from pose.manifold.regressors import RBFNetwork
from pose.orientation import keypoint_heading
from pose.rotations import geodesic_deg, inplane_heading, rot_z
from pose.synthetic import card_texture
from pose.vocabulary import learn_vocabulary, word_histogram


def _wrap_deg(a):
    return np.degrees(np.angle(np.exp(1j * np.asarray(a))))


@pytest.mark.parametrize("turn_deg", [30.0, -75.0, 160.0])
def test_sift_angles_turn_with_the_image_in_image_axes(turn_deg):
    img = np.full((240, 320, 3), 90, np.uint8)
    img[60:180, 100:220] = card_texture(seed=3, size=120)
    # getRotationMatrix2D's positive angle turns from v to u; negate it for u -> v
    M = cv2.getRotationMatrix2D((160.0, 120.0), -turn_deg, 1.0)
    turned = cv2.warpAffine(img, M, (320, 240), borderValue=(90, 90, 90))
    f, g = extract_sift(img), extract_sift(turned)
    sim = f.descriptors @ g.descriptors.T
    j = sim.argmax(axis=1)
    moved = np.c_[f.xy, np.ones(len(f))] @ M.T
    same = (sim.max(axis=1) > 0.9) & (np.linalg.norm(moved - g.xy[j], axis=1) < 1.5)
    assert same.sum() >= 20
    assert np.median(_wrap_deg(g.angles[j] - f.angles)[same]) == pytest.approx(turn_deg, abs=2)


def test_keypoint_heading_finds_the_vote_peak_despite_outliers():
    rng = np.random.default_rng(0)
    canonical = rng.uniform(-np.pi, np.pi, 200)
    heading = np.radians(-170.0)  # near the wrap-around
    angles = canonical + heading + rng.normal(0, np.radians(2), 200)
    angles[:60] = rng.uniform(-np.pi, np.pi, 60)  # 30 % of the keypoints vote at random
    h, agree = keypoint_heading(angles, canonical)
    assert _wrap_deg(h - heading) == pytest.approx(0.0, abs=1.0)
    assert 0.65 < agree < 0.85
    assert keypoint_heading(np.zeros(0), np.zeros(0)) == (0.0, 0.0)


def test_inplane_heading_turns_with_the_object_about_the_optical_axis():
    rng = np.random.default_rng(1)
    for _ in range(10):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        w, x, y, z = q
        R = np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
            ]
        )
        d = rng.uniform(-np.pi, np.pi)
        assert _wrap_deg(inplane_heading(rot_z(d) @ R) - inplane_heading(R) - d) == pytest.approx(
            0.0, abs=1e-6
        )
        rel = rot_z(-inplane_heading(R)) @ R
        turned = rot_z(d) @ R
        assert geodesic_deg(rot_z(-inplane_heading(turned)) @ turned, rel) < 1e-3


def test_visual_words_are_seeded_and_histograms_normalised():
    rng = np.random.default_rng(2)
    d = rng.random((500, 128)).astype(np.float32)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    w1, w2 = learn_vocabulary(d, 16, seed=4), learn_vocabulary(d, 16, seed=4)
    np.testing.assert_array_equal(w1, w2)
    np.testing.assert_allclose(np.linalg.norm(w1, axis=1), 1.0, atol=1e-5)
    h = word_histogram(d[:50], w1)
    assert h.shape == (16,) and np.sum(h**2) == pytest.approx(1.0)
    assert not word_histogram(np.zeros((0, 128), np.float32), w1).any()
    with pytest.raises(ValueError, match="at least n_words"):
        learn_vocabulary(d[:10], 16)


def test_normalised_rbf_keeps_piecewise_constant_targets_sharp():
    """Three clusters with one target each: a narrow normalised RBF answers each cluster's own
    target, even for points beyond the training data, where a plain RBF decays to the bias."""
    rng = np.random.default_rng(3)
    centres = np.array([[0.0, 0.0], [4.0, 0.0], [0.0, 4.0]])
    X = np.concatenate([c + rng.normal(0, 0.3, (30, 2)) for c in centres])
    y = np.repeat(np.eye(3), 30, axis=0)
    sharp = RBFNetwork(n_centers=1000, width_scale=0.1, normalized=True).fit(X, y)
    assert len(sharp.centers_) == 90  # one unit per sample, no k-means
    far = np.array([[-3.0, -3.0], [9.0, 0.0], [0.0, 9.0]])
    np.testing.assert_allclose(sharp.predict(np.r_[centres, far]), np.r_[np.eye(3), np.eye(3)],
                               atol=0.05)  # fmt: skip
    plain = RBFNetwork(n_centers=1000, width_scale=0.1).fit(X, y)
    assert np.abs(plain.predict(far) - np.eye(3)).max() > 0.3


def test_occlusion_augmentation_hides_the_stated_fraction():
    img = np.full((240, 320, 3), 90, np.uint8)
    img[60:180, 100:220] = card_texture(seed=5, size=120)
    mask = np.zeros((240, 320), bool)
    mask[60:180, 100:220] = True
    f = extract_sift(img, mask)
    rng = np.random.default_rng(0)
    for frac in (0.3, 0.6):
        g, visible = occlude_features(f, mask, frac, rng)
        assert visible.sum() / mask.sum() == pytest.approx(1 - frac, abs=0.02)
        assert not (visible & ~mask).any()
        inside = visible[np.round(g.xy[:, 1]).astype(int), np.round(g.xy[:, 0]).astype(int)]
        assert inside.mean() > 0.95 and 0 < len(g) < len(f)
