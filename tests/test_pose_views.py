"""Rendered training views (real MuJoCo rendering): occlusion, cache, and fit/predict on them."""

import numpy as np
import pytest

from pose.manifold.estimator import PoseManifoldEstimator
from pose.metrics import rotation_error_deg
from scorbot_gym.data.views import PoseSample, grid_poses, occlude, random_poses, render_views
from scorbot_gym.objects import get_object

W, H = 320, 240


def test_occluder_hides_the_requested_fraction():
    mask = np.zeros((120, 160), bool)
    mask[30:90, 40:120] = True
    img = np.full((120, 160, 3), 200, np.uint8)
    rng = np.random.default_rng(0)
    for f in (0.0, 0.25, 0.5, 0.95):
        out, visible, achieved = occlude(img, mask, f, rng)
        assert achieved == pytest.approx(f, abs=0.03)
        assert not (visible & ~mask).any()
        changed = (out != img).any(axis=2)
        assert not (changed & visible).any()  # visible object pixels are untouched
    with pytest.raises(ValueError, match=r"within \[0, 0.95\]"):
        occlude(img, mask, 0.99, rng)


def test_grid_and_random_poses_are_seeded():
    g = grid_poses(2, 90.0, n_positions=2, seed=3)
    assert len(g) == 2 * 4 * 2 and {s.resting_index for s in g} == {0, 1}
    assert g == grid_poses(2, 90.0, n_positions=2, seed=3)
    b = ((0.2, 0.3), (-0.1, 0.1))
    assert random_poses(5, 3, b, seed=1) == random_poses(5, 3, b, seed=1)
    assert random_poses(5, 3, b, seed=1) != random_poses(5, 3, b, seed=2)


@pytest.fixture(scope="session")
def brick_views(tmp_path_factory):
    cache = tmp_path_factory.mktemp("views")
    train = render_views("foam_brick", grid_poses(1, 30.0, n_positions=1, seed=0), width=W,
                         height=H, cache_dir=cache, progress=False)  # fmt: skip
    rng = np.random.default_rng(4)
    # headings within 8 degrees of the 30-degree training grid, at new table positions
    samples = [
        PoseSample(
            float(rng.uniform(0.25, 0.31)),
            float(rng.uniform(-0.05, 0.05)),
            float(np.radians(30 * k + rng.uniform(-8, 8))),
        )
        for k in range(4)
    ]
    test = render_views("foam_brick", samples, width=W, height=H, occlusion=[0, 0, 0.3, 0.3],
                        seed=2, cache_dir=cache, progress=False)  # fmt: skip
    return cache, train, test, samples


def test_rendered_views_are_labelled_and_cached(brick_views):
    cache, train, test, samples = brick_views
    v = train[0]
    assert v.view.image.shape == (H, W, 3) and v.view.mask.any()
    assert v.view.object_name == "foam_brick"
    # the ground truth agrees with the camera: the object's origin projects inside its mask
    u, w = v.view.camera.project(v.world_from_object[:3, 3])[0]
    assert v.view.mask[int(round(w)), int(round(u))]
    np.testing.assert_allclose(
        v.camera_from_object, v.view.camera.camera_from_world @ v.world_from_object
    )
    assert [t.occlusion for t in test] == pytest.approx([0, 0, 0.3, 0.3], abs=0.03)
    again = render_views("foam_brick", samples, width=W, height=H, occlusion=[0, 0, 0.3, 0.3],
                         seed=2, cache_dir=cache, progress=False)  # fmt: skip
    for a, b in zip(test, again, strict=True):
        np.testing.assert_array_equal(a.view.image, b.view.image)
    assert len(list((cache / "views").glob("*.npz"))) == 2
    assert not list((cache / "views").glob("*.tmp"))


def test_fit_predict_on_rendered_views(brick_views):
    _, train, test, _ = brick_views
    est = PoseManifoldEstimator().set_params(
        bunches__n_bunches=6, regressor__n_centers=8, matcher__min_inliers=6
    )
    est.fit([v.view for v in train], [v.camera_from_object for v in train])
    sym = get_object("foam_brick").symmetry
    errs = []
    for lv in test:
        e = est.predict(lv.view)
        assert e.valid, e.reason
        errs.append(rotation_error_deg(e.rotation, lv.camera_from_object[:3, :3], sym))
    assert max(errs) < 5.0, errs


def test_unknown_object_lists_the_valid_names():
    with pytest.raises(KeyError, match="valid objects"):
        render_views("teapot", [PoseSample(0.28, 0.0, 0.0)], progress=False)


def test_depth_views_lift_mask_pixels_onto_the_object(tmp_path):
    samples = random_poses(2, 1, ((0.25, 0.3), (-0.05, 0.05)), seed=4)
    views = render_views("box", samples, "top", 160, 120, 0.3, 0, tmp_path, False, depth=True)
    for lv in views:
        v = lv.view
        assert v.depth is not None and v.depth.shape == (120, 160)
        vs, us = np.nonzero(v.mask)
        z = v.depth[vs, us]
        assert np.all(z > 0)
        rays = np.c_[us, vs, np.ones(len(us))] @ np.linalg.inv(v.camera.K).T
        pts_cam = rays * z[:, None]
        T = lv.camera_from_object
        pts_obj = (pts_cam - T[:3, 3]) @ T[:3, :3]  # camera -> object frame
        half = get_object("box").model.half_extents
        assert np.all(np.abs(pts_obj) <= half + 0.004)
    # the same call is served from the cache, depth included
    again = render_views("box", samples, "top", 160, 120, 0.3, 0, tmp_path, False, depth=True)
    np.testing.assert_array_equal(again[0].view.depth, views[0].view.depth)


def test_training_where_the_object_is_too_small_says_so(tmp_path):
    """From the hand camera's home pose, 0.44 m above the table, a golf ball in a 160x120 image
    has too few keypoints for the estimator's vocabulary: the error names object, camera, size."""
    from scorbot_gym.perception.training import train_object

    with pytest.raises(ValueError, match="pose model of 'golf_ball' from camera 'eye_in_hand'"):
        train_object(
            "golf_ball", 2, "eye_in_hand", 160, 120, cache_dir=str(tmp_path), progress=False
        )
