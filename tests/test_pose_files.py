"""Damaged files: view-cache entries heal, model files fail at load with a message that says
what is wrong, and a model never answers a valid non-finite pose."""

import copy
import json
import os
import time
import warnings

import numpy as np
import pytest

from pose.fileio import atomic_savez
from pose.manifold.estimator import PoseManifoldEstimator
from pose.model_set import PoseModelSet
from pose.serialization import FORMAT
from pose.synthetic import card_views
from scorbot_gym.data.views import PoseSample, render_views

SAMPLES = [PoseSample(0.26, -0.03, 0.4), PoseSample(0.3, 0.04, 2.0)]


def _render(cache):
    return render_views("foam_brick", SAMPLES, width=160, height=120, cache_dir=cache,
                        progress=False)  # fmt: skip


@pytest.fixture(scope="module")
def cached(tmp_path_factory):
    cache = tmp_path_factory.mktemp("views")
    views = _render(cache)
    (entry,) = (cache / "views").glob("*.npz")
    return cache, entry, entry.read_bytes(), views


def _truncate(data: bytes) -> bytes:
    return data[: len(data) // 2]


def _flip(data: bytes) -> bytes:  # the middle of the file lies in the compressed images
    b = bytearray(data)
    for i in range(len(b) // 2, len(b) // 2 + 16):
        b[i] ^= 0xFF
    return bytes(b)


@pytest.mark.parametrize("damage", [_truncate, _flip, lambda d: b"", lambda d: b"text\n" * 9])
def test_unreadable_view_cache_entry_is_rendered_again(cached, damage):
    cache, entry, good, views = cached
    entry.write_bytes(damage(good))
    with pytest.warns(RuntimeWarning, match="discarding unreadable cache entry"):
        again = _render(cache)
    for a, b in zip(views, again, strict=True):
        np.testing.assert_array_equal(a.view.image, b.view.image)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # healed: the next read is silent
        _render(cache)


def test_orphaned_temporary_files_are_removed_later(cached):
    cache = cached[0]
    old = cache / "views" / ".abc.npz.x1y2.tmp"
    fresh = cache / "views" / ".abc.npz.z3w4.tmp"
    old.write_bytes(b"half a write")
    fresh.write_bytes(b"a write in progress")
    hour_ago = time.time() - 3600
    os.utime(old, (hour_ago, hour_ago))
    _render(cache)
    assert not old.exists()
    assert fresh.exists()  # could be another process's write: left alone


# ------------------------------------------------------------------------------- model files
@pytest.fixture(scope="module")
def model(tmp_path_factory):
    yaws = np.radians(np.arange(0, 360, 30))
    views, poses = card_views(np.array([(0.02, -0.01, a) for a in yaws]))
    est = PoseManifoldEstimator().set_params(bunches__n_bunches=6).fit(views, poses)
    path = tmp_path_factory.mktemp("model") / "card.npz"
    est.save(path)
    test_views, _ = card_views(np.array([[0.0, 0.01, 1.0], [-0.03, 0.0, 4.0]]))
    return est, path, test_views


@pytest.mark.parametrize(
    "content",
    [b"hello, this is a text file\n", bytes(np.random.default_rng(0).integers(0, 256, 999)),
     b"\x93NUMPY\x01\x00v\x00"],
    ids=["text", "random", "npy"],
)  # fmt: skip
@pytest.mark.parametrize("loader", [PoseManifoldEstimator.load, PoseModelSet.load])
def test_a_non_model_file_is_named_as_such(tmp_path, content, loader):
    path = tmp_path / "notes.npz"
    path.write_bytes(content)
    with pytest.raises(ValueError, match="is not a scorbot-gym model file") as err:
        loader(path)
    assert "allow_pickle" not in str(err.value)


def test_a_truncated_model_file_is_corrupt(model, tmp_path):
    path = tmp_path / "cut.npz"
    path.write_bytes(model[1].read_bytes()[:5000])
    with pytest.raises(ValueError, match="corrupt model file .*re-train"):
        PoseManifoldEstimator.load(path)


def _rewrite(src, dst, change, version=None):
    with np.load(src) as z:
        arrays = {k: z[k] for k in z.files}
    header = json.loads(str(arrays.pop("__header__")))
    if version is not None:
        header["format_version"] = version
    change(arrays)
    atomic_savez(dst, __header__=np.array(json.dumps(header)), **arrays)
    return dst


def _set(key, fn):
    def change(arrays):
        arrays[key] = fn(arrays[key].copy())

    return change


def _nan_at_0(a):
    a.flat[0] = np.nan
    return a


@pytest.mark.parametrize(
    "change, message",
    [
        (_set("x_scale_", _nan_at_0), "x_scale_ holds non-finite"),
        (_set("rot/centers_", _nan_at_0), "rot/centers_ holds non-finite|rotation regressor"),
        (_set("db_desc_", lambda a: a[:-5]), r"db_desc_ has shape .* to match db_xy_"),
        (_set("db_view_", lambda a: a + 100), "db_view_ must hold view numbers"),
        (_set("view_size_", lambda a: a[:3]), "view_size_ has shape"),
        (_set("rot/weights_", lambda a: a[:-3]), "rotation regressor does not take"),
        (_set("rot/weights_", lambda a: a[:, :4]), r"rotation regressor gives \(1, 4\)"),
        (_set("x_mean_", lambda a: a[:20]), "x_mean_ and x_scale_ must be equal-length"),
        (_set("words_", lambda a: a[:, :64]), r"words_ has shape .*expected \(n_words, 128\)"),
        (lambda arrays: arrays.pop("db_phi_"), "missing or has bad entries"),
    ],
    ids=lambda v: v if isinstance(v, str) else "",
)
def test_inconsistent_model_arrays_fail_at_load(model, tmp_path, change, message):
    path = _rewrite(model[1], tmp_path / "bad.npz", change)
    with pytest.raises(ValueError, match=message) as err:
        PoseManifoldEstimator.load(path)
    assert "re-train" in str(err.value)
    with pytest.raises(ValueError, match=message):
        PoseModelSet.load(path)


def test_predict_never_answers_a_valid_non_finite_pose(model):
    est, _, views = model
    broken = copy.deepcopy(est)
    broken.regressor_.weights_[:] = np.nan
    for e in broken.predict(views):
        assert not e.valid and "non-finite" in e.reason
        assert np.isnan(e.rotation).all() and np.isnan(e.translation).all()
    assert all(e.valid for e in est.predict(views))


def test_version_2_files_load_as_the_equivalent_stages(model, tmp_path):
    """A file written before the stages existed (flat parameters) gives the same estimator."""
    est, path, views = model
    flat = dict(
        n_bunches=6, reference="keypoints", regressor="rbf", n_centers=1000, width_scale=0.1,
        ridge=1e-4, normalized_rbf=True, use_shape=True, shape_weight=1.0, n_words=32,
        words_weight=3.0, augment_occlusion=[0.3, 0.6], appearance_weight=1.0,
        geometry_weight=2.0, max_train_features=200, contrast_threshold=0.03, ratio=0.85,
        ransac_method="ransac", ransac_threshold=4.0, min_inliers=8, n_candidates=4, refine=True,
        allocentric=False, random_state=0,
    )  # fmt: skip
    old = _rewrite(
        path, tmp_path / "v2.npz", _set("params", lambda _: np.array(json.dumps(flat))), 2
    )
    v2, v3 = PoseManifoldEstimator.load(old), PoseManifoldEstimator.load(path)
    assert v2.bunches.n_bunches == 6 and v2.refiner is not None
    assert v2.featurizer.blocks == ("bunches", "shape", "words")
    for a, b in zip(v2.predict(views), v3.predict(views), strict=True):
        np.testing.assert_array_equal(a.rotation, b.rotation)
        np.testing.assert_array_equal(a.translation_regressed, b.translation_regressed)
    flat.update(refine=False, use_shape=False, reference="silhouette")
    bad = _rewrite(
        path, tmp_path / "v2b.npz", _set("params", lambda _: np.array(json.dumps(flat))), 2
    )
    with pytest.raises(ValueError, match="need 38 feature columns, its arrays hold 113"):
        PoseManifoldEstimator.load(bad)
    header_ok = json.loads(str(np.load(path)["__header__"]))
    assert header_ok["format"] == FORMAT and header_ok["format_version"] == 3
