"""The estimator end to end on synthetic card views with exactly known poses (fast)."""

import json

import numpy as np
import pytest
from sklearn.base import clone

from pose.manifold import ScipyRBF, SilhouetteDirection
from pose.manifold.estimator import PoseManifoldEstimator
from pose.metrics import rotation_error_deg, translation_error
from pose.model_set import PoseModelSet
from pose.synthetic import card_views, top_camera
from pose.view import View

PARAMS = dict(bunches__n_bunches=6, regressor__n_centers=24, random_state=0)


def small(**params) -> PoseManifoldEstimator:
    """The default composition, made smaller for the card (and ``params`` on top)."""
    return PoseManifoldEstimator().set_params(**PARAMS).set_params(**params)


def _train_poses():
    yaws = np.radians(np.arange(0, 360, 15))
    return np.array([(x, y, a) for a in yaws for x, y in ((-0.04, 0.03), (0.04, -0.03))])


@pytest.fixture(scope="session")
def card_data():
    views, poses = card_views(_train_poses())
    rng = np.random.default_rng(11)
    test = np.c_[rng.uniform(-0.06, 0.06, 8), rng.uniform(-0.04, 0.04, 8), rng.uniform(0, 6.28, 8)]
    tviews, tposes = card_views(test)
    return views, poses, tviews, tposes


@pytest.fixture(scope="session")
def card_model(card_data):
    views, poses, _, _ = card_data
    return small().fit(views, poses)


def test_refined_pose_of_held_out_views(card_model, card_data):
    _, _, tviews, tposes = card_data
    for v, p in zip(tviews, tposes, strict=True):
        e = card_model.predict(v)
        assert e.valid, e.reason
        assert rotation_error_deg(e.rotation, p[:3, :3]) < 1.0
        assert translation_error(e.translation, p[:3, 3]) < 0.005
        assert 0.0 < e.confidence <= 1.0 and e.n_inliers >= card_model.matcher.min_inliers
        np.testing.assert_allclose(e.rotation_coarse @ e.rotation_coarse.T, np.eye(3), atol=1e-9)
        assert set(e.timings_ms) == {"sift", "match", "manifold", "regress", "refine", "total"}


def test_no_refiner_returns_the_pure_manifold_rotation(card_model, card_data):
    views, poses, tviews, tposes = card_data
    coarse = clone(card_model).set_params(refiner=None).fit(views, poses)
    errs = []
    for v, p in zip(tviews, tposes, strict=True):
        a, b = card_model.predict(v), coarse.predict(v)
        np.testing.assert_allclose(b.rotation, a.rotation_coarse, atol=1e-12)
        errs.append(rotation_error_deg(b.rotation, p[:3, :3]))
    # the keypoint heading and the one-unit-per-sample RBF: well under a degree on the card
    assert np.median(errs) < 2.0 and max(errs) < 5.0, errs


def test_silhouette_reference_is_kept_as_an_ablation(card_data):
    views, poses, tviews, tposes = card_data
    est = small(reference=SilhouetteDirection(), refiner=None).fit(views, poses)
    pairs = zip(tviews, tposes, strict=True)
    errs = [rotation_error_deg(est.predict(v).rotation, p[:3, :3]) for v, p in pairs]
    # coarse but informative: a random heading would be 90 degrees off on average
    assert np.median(errs) < 25.0, errs


def _blank_view(mask=None):
    cam = top_camera()
    return View(np.full((cam.height, cam.width, 3), 128, np.uint8), cam, mask)


@pytest.mark.parametrize("case", ["blank", "fully_occluded", "out_of_view", "other_texture"])
def test_unusable_views_are_invalid_not_errors(case, card_model):
    if case == "blank":
        view = _blank_view()
    elif case == "fully_occluded":
        views, _ = card_views(np.array([[0.0, 0.0, 0.3]]))
        view = View(views[0].image, views[0].camera, np.zeros_like(views[0].mask))
    elif case == "out_of_view":
        views, _ = card_views(np.array([[0.6, 0.0, 0.3]]))  # far off the image
        view = views[0]
    else:  # a card the model never saw: nothing matches geometrically
        views, _ = card_views(np.array([[0.0, 0.0, 0.3]]), texture_seed=99)
        view = views[0]
    e = card_model.predict(view)
    assert not e.valid and e.reason
    assert np.isnan(e.rotation).all() and np.isnan(e.translation).all()
    assert e.timings_ms["total"] >= 0


def test_same_seed_same_model_and_predictions(card_model, card_data):
    views, poses, tviews, _ = card_data
    other = small().fit(views, poses)
    a, b = card_model.to_arrays(), other.to_arrays()
    assert a.keys() == b.keys()
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    for v in tviews[:3]:
        np.testing.assert_array_equal(card_model.predict(v).rotation, other.predict(v).rotation)


def test_save_load_round_trip(card_model, card_data, tmp_path):
    path = tmp_path / "card.npz"
    card_model.save(path)
    loaded = PoseManifoldEstimator.load(path)
    assert repr(loaded.get_params(deep=True)) == repr(card_model.get_params(deep=True))
    v = card_data[2][0]
    np.testing.assert_array_equal(loaded.predict(v).rotation, card_model.predict(v).rotation)
    assert not list(tmp_path.glob("*.tmp"))  # the temporary file was renamed into place


def test_corrupt_and_wrong_version_files_raise_clear_errors(card_model, tmp_path):
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip file at all")
    with pytest.raises(ValueError, match="not a scorbot-gym model file"):
        PoseManifoldEstimator.load(bad)
    good = tmp_path / "good.npz"
    card_model.save(good)
    with np.load(good) as z:
        arrays = {k: z[k] for k in z.files}
    header = json.loads(str(arrays["__header__"]))
    header["format_version"] = 999
    arrays["__header__"] = np.array(json.dumps(header))
    old = tmp_path / "old.npz"
    np.savez(old, **arrays)
    with pytest.raises(ValueError, match="version 999 is not supported"):
        PoseManifoldEstimator.load(old)
    with pytest.raises(FileNotFoundError):
        PoseManifoldEstimator.load(tmp_path / "missing.npz")


def test_model_set_dispatches_by_object_name(card_model, card_data, tmp_path):
    models = PoseModelSet({"card": card_model})
    path = tmp_path / "set.npz"
    models.save(path, meta={"camera": "top"})
    loaded = PoseModelSet.load(path)
    assert loaded.object_names == ["card"] and loaded.meta["camera"] == "top"
    assert loaded.predict(card_data[2][0]).valid
    with pytest.raises(KeyError, match="this file has \\['card'\\]"):
        loaded["mug"]


def test_params_and_bad_input(card_data):
    est = small(bunches__n_bunches=5)
    assert est.set_params(bunches__n_bunches=7).get_params()["bunches__n_bunches"] == 7
    views, poses = card_data[:2]
    with pytest.raises(ValueError, match="n_bunches must be >= 2"):
        small(bunches__n_bunches=1).fit(views, poses)
    with pytest.raises(ValueError, match="reference must be a stage object with validate"):
        PoseManifoldEstimator(reference="axis").fit(views, poses)
    with pytest.raises(ValueError, match="regressor must be a regressor with fit/predict"):
        PoseManifoldEstimator(regressor="mlp").fit(views, poses)
    with pytest.raises(ValueError, match="blocks must be distinct names from"):
        small(featurizer__blocks=("bunches", "colour")).fit(views, poses)
    with pytest.raises(ValueError, match="min_inliers must be >= 4"):
        small(matcher__min_inliers=3).fit(views, poses)
    with pytest.raises(ValueError, match="camera_from_object"):
        PoseManifoldEstimator().fit(views, poses[:-1])
    with pytest.raises(ValueError, match="at least 8 SIFT keypoints"):
        PoseManifoldEstimator().fit([_blank_view()] * 3, np.stack([np.eye(4)] * 3))
    with pytest.raises(ValueError, match="image is 100x100 but the camera model is 320x240"):
        View(np.zeros((100, 100, 3), np.uint8), top_camera())
    with pytest.raises(ValueError, match="uint8"):
        View(np.zeros((240, 320), np.float32), top_camera())


def test_scipy_regressor_alternative(card_data):
    views, poses, tviews, tposes = card_data
    est = small(regressor=ScipyRBF(smoothing=1e-4, standardize=False)).fit(views, poses)
    e = est.predict(tviews[0])
    assert e.valid and rotation_error_deg(e.rotation, tposes[0][:3, :3]) < 1.0


def test_views_without_masks(card_data):
    """No segmentation at all: keypoints from the whole image, shape block left neutral."""
    views, poses, tviews, tposes = card_data
    bare = [View(v.image, v.camera) for v in views]
    est = small().fit(bare, poses)
    assert np.isfinite(est.featurizer_.x_mean_).all()
    for v, p in zip(tviews[:3], tposes[:3], strict=True):
        e = est.predict(View(v.image, v.camera))
        assert e.valid, e.reason
        assert rotation_error_deg(e.rotation, p[:3, :3]) < 2.0
