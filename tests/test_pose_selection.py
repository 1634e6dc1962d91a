"""ValidationSelection on real rendered views: the choice, symmetry, save/load, the runner."""

import numpy as np
import pytest
from sklearn.base import clone

from pose import baselines
from pose.composition import fit_estimator
from pose.fallback import ConfidenceFallback
from pose.registry import estimator_names, make_from_spec
from pose.selection import ValidationSelection
from pose.symmetry import Symmetry
from pose.view import View
from scorbot_gym.objects import get_object

OBJECT = "potted_meat_can"


@pytest.fixture(scope="session")
def fitted(can_views):
    train, poses, _ = can_views
    return make_from_spec("select(estimators=('chance', 'sift-pnp'))").fit(train, poses)


class _Recorder(baselines.ChanceEstimator):
    """The chance baseline, remembering what its ``fit`` was given."""

    def fit(self, views, poses, symmetry=None):
        type(self).calls.append((len(views), symmetry))
        return super().fit(views, poses)


def test_registered_and_built_from_specs():
    assert "select" in estimator_names()
    est = make_from_spec("select(estimators=('sift-pnp(upscale=2)', 'pca-rbf'), random_state=3)")
    assert isinstance(est, ValidationSelection) and est.random_state == 3
    (n0, e0), (n1, e1) = est.estimators
    assert (n0, n1) == ("sift-pnp(upscale=2)", "pca-rbf")
    assert isinstance(e0, baselines.SiftPnPEstimator) and e0.upscale == 2
    assert clone(est).get_params()["cv"] == 4


def test_picks_the_candidate_that_validates_better(fitted, can_views):
    # keypoint PnP finds a textured can's pose; the image-blind answer does not
    assert fitted.candidate_names_ == ["chance", "sift-pnp"]
    assert fitted.best_name_ == "sift-pnp" and fitted.best_index_ == 1
    assert isinstance(fitted.best_estimator_, baselines.SiftPnPEstimator)
    assert fitted.validation_success_[1] > fitted.validation_success_[0]
    train, poses, test = can_views
    direct = baselines.SiftPnPEstimator().fit(train, poses)
    for lv in test:
        np.testing.assert_allclose(
            fitted.predict(lv.view).rotation, direct.predict(lv.view).rotation, atol=1e-9
        )
    assert fitted.score([lv.view for lv in test], [lv.camera_from_object for lv in test]) >= 0.5


@pytest.mark.slow
def test_folds_share_each_views_sift_and_answer_as_without_sharing(can_views, monkeypatch):
    import contextlib

    from pose.features import keypoints as kp

    train, poses, test = can_views
    spec = "select(estimators=('manifold-pnp', 'manifold-pnp(matcher__min_inliers=6)'))"
    keys = []
    detect = kp._detect_sift

    def counted(image, mask, *settings):
        keys.append((kp._digest(image, mask), settings))
        return detect(image, mask, *settings)

    monkeypatch.setattr(kp, "_detect_sift", counted)
    shared = make_from_spec(spec).fit(train, poses)
    # two candidates x (4 fold fits + 4 fold predictions) + the refit: each view's SIFT runs
    # once as a training view and once as a query, not nine times
    assert len(keys) == len(set(keys)) == 2 * len(train)
    monkeypatch.setattr("pose.selection.shared_keypoints", contextlib.nullcontext)
    alone = make_from_spec(spec).fit(train, poses)
    assert len(keys) > 2 * len(train) * 4
    a, b = shared.to_arrays(), alone.to_arrays()
    assert a.keys() == b.keys()
    for k in a:  # NaN: a keypoint without depth
        assert np.array_equal(a[k], b[k], equal_nan=a[k].dtype.kind == "f"), k
    view = test[0].view
    assert np.array_equal(shared.predict(view).rotation, alone.predict(view).rotation)


def test_split_is_seeded_and_symmetry_reaches_candidates(can_views):
    train, poses, _ = can_views
    _Recorder.calls = []
    sym = get_object(OBJECT).symmetry
    est = ValidationSelection([("a", _Recorder()), ("b", baselines.ChanceEstimator())], cv=3)
    fit_estimator(est, train, poses, sym)
    # one fit per fold on the other two folds, then the winner (first of two equals) on all
    sizes = [len(train) - len(f) for f in np.array_split(np.arange(len(train)), 3)]
    assert _Recorder.calls == [(n, sym) for n in sizes] + [(len(train), sym)]
    assert est.best_name_ == "a"
    again = clone(est).fit(train, poses, symmetry=sym)
    np.testing.assert_array_equal(again.validation_success_, est.validation_success_)


def test_symmetry_changes_what_counts_as_right(can_views):
    # a constant answer misses the can's heading; with a continuous symmetry about the
    # vertical it is right on every view of the same resting face
    train, poses, _ = can_views
    est = ValidationSelection([baselines.ChanceEstimator()])
    R0 = np.eye(3)
    P = poses.copy()
    for i, a in enumerate(np.linspace(0, 2 * np.pi, len(P), endpoint=False)):
        c, s = np.cos(a), np.sin(a)
        P[i, :3, :3] = R0 @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    two = ValidationSelection([baselines.ChanceEstimator(), baselines.ChanceEstimator()])
    plain = clone(two).fit(train, P)
    axial = clone(two).fit(train, P, symmetry=Symmetry("axial", axis=(0.0, 0.0, 1.0)))
    assert axial.validation_success_[0] == 1.0 > plain.validation_success_[0]
    assert np.isnan(est.fit(train, P).validation_success_).all()  # one candidate: no validation


class _Leaning(baselines.ChanceEstimator):
    """The chance baseline's answer tipped 3 degrees: right within 5 degrees, never exact."""

    def predict(self, view):
        e = super().predict(view)
        c, s = np.cos(np.radians(3.0)), np.sin(np.radians(3.0))
        e.rotation = e.rotation @ np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
        return e


def test_equal_success_goes_to_the_smaller_median_error(can_views):
    # Every training pose of an upright, axially symmetric object is the same pose: any
    # upright answer is right, and the constant answer (the null model) is the exact one.
    train, poses, _ = can_views
    P = poses.copy()
    for i in range(len(P)):
        c, s = np.cos(np.radians(30.0 * i)), np.sin(np.radians(30.0 * i))
        P[i, :3, :3] = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    P[:, :3, :3] = np.einsum("nij,njk->nik", np.stack([v.camera.camera_from_world[:3, :3]
                                                       for v in train]), P[:, :3, :3])  # fmt: skip
    est = ValidationSelection([("leaning", _Leaning()), ("null", baselines.ChanceEstimator())])
    est.fit(train, P, symmetry=Symmetry("axial", axis=(0.0, 0.0, 1.0)))
    np.testing.assert_array_equal(est.validation_success_, [1.0, 1.0])
    assert est.validation_median_deg_[0] > 2.9 and est.validation_median_deg_[1] < 1e-3
    assert est.best_name_ == "null"


def test_repeated_candidates_get_distinct_names(can_views):
    train, poses, _ = can_views
    est = ValidationSelection([baselines.ChanceEstimator(), baselines.PCAEstimator(),
                               baselines.ChanceEstimator()]).fit(train, poses)  # fmt: skip
    assert est.candidate_names_ == ["ChanceEstimator-1", "PCAEstimator", "ChanceEstimator-2"]
    with pytest.raises(ValueError, match="candidate names must be unique, got 'pca-rbf' more"):
        make_from_spec("select(estimators=('pca-rbf', 'pca-rbf'))").fit(train, poses)


def test_candidate_that_cannot_fit_is_passed_over(can_views):
    train, poses, _ = can_views
    est = ValidationSelection([("sift", baselines.SiftPnPEstimator()), ("chance", _Recorder())])
    blank = [View(np.zeros_like(v.image), v.camera, v.mask, v.object_name, v.depth) for v in train]
    _Recorder.calls = []
    est.fit(blank, poses)
    assert est.best_name_ == "chance" and "sift" in est.fit_errors_
    assert np.isnan(est.validation_success_[0])
    both = "fitted on these views: SiftPnPEstimator-1: .*; SiftPnPEstimator-2: "
    with pytest.raises(ValueError, match=both):
        ValidationSelection([baselines.SiftPnPEstimator(), baselines.SiftPnPEstimator()]).fit(
            blank, poses
        )


def test_save_load_round_trip(fitted, can_views, tmp_path):
    path = tmp_path / "select.npz"
    fitted.save(path)
    loaded = ValidationSelection.load(path)
    assert loaded.best_name_ == "sift-pnp" and loaded.candidate_names_ == ["chance", "sift-pnp"]
    np.testing.assert_array_equal(loaded.validation_success_, fitted.validation_success_)
    for lv in can_views[2]:
        a, b = fitted.predict(lv.view), loaded.predict(lv.view)
        np.testing.assert_allclose(b.rotation, a.rotation, atol=1e-6)
    with pytest.raises(ValueError, match="not a ValidationSelection"):
        fitted.best_estimator_.save(tmp_path / "pnp.npz")
        ValidationSelection.load(tmp_path / "pnp.npz")
    arrays = dict(np.load(path))
    arrays["selection_params"] = np.array("{")
    with pytest.raises(ValueError, match="selection model file is missing or has bad entries"):
        ValidationSelection.from_arrays(arrays)


def test_nested_in_a_fallback_round_trips(can_views, tmp_path):
    train, poses, test = can_views
    spec = "fallback(estimator=\"select(estimators=('chance', 'pca-nn'))\")"
    est = make_from_spec(spec)
    fit_estimator(est, train, poses, get_object(OBJECT).symmetry)
    assert isinstance(est.estimator_, ValidationSelection)
    est.save(tmp_path / "f.npz")
    loaded = ConfidenceFallback.load(tmp_path / "f.npz")
    assert loaded.estimator_.best_name_ == est.estimator_.best_name_
    for lv in test[:2]:
        np.testing.assert_allclose(
            loaded.predict(lv.view).rotation, est.predict(lv.view).rotation, atol=1e-6
        )


@pytest.mark.parametrize(
    "params, match",
    [
        ({"estimators": ()}, "at least one candidate"),
        ({"estimators": "pca-rbf"}, "non-empty sequence"),
        ({"estimators": [3]}, r"estimators\[0\] must be a pose estimator"),
        ({"cv": 1}, "cv must be at least 2 folds"),
        ({"cv": "4"}, "cv must be an integer"),
        ({"random_state": 0.5}, "random_state must be an integer"),
    ],
)
def test_bad_parameters_are_one_line_errors(params, match, can_views):
    train, poses, _ = can_views
    est = ValidationSelection([baselines.ChanceEstimator(), baselines.PCAEstimator()])
    with pytest.raises(ValueError, match=match):
        est.set_params(**params).fit(train, poses)


def test_too_few_views_to_split_is_refused(can_views):
    train, poses, _ = can_views
    est = ValidationSelection([baselines.ChanceEstimator(), baselines.PCAEstimator()], cv=5)
    with pytest.raises(ValueError, match="cv=5 folds need at least 5 training views, got 3"):
        est.fit(train[:3], poses[:3])
    with pytest.raises(ValueError, match="select needs a tuple of estimator specs"):
        make_from_spec("select(estimators='pca-rbf')")


@pytest.mark.slow
def test_sweep_job_fits_the_selection_with_the_objects_symmetry(tmp_path, monkeypatch):
    """In a sweep the manifold cannot be fitted on the golf ball in the overview camera (too
    few keypoints): the selection passes it over, answers with the other candidate, and gets
    the object's symmetry from the runner; the cached model file reloads."""
    from pathlib import Path

    from scorbot_gym.experiments.trial import ModelJob, model_key, run_model_job

    seen = []
    real = ValidationSelection.fit

    def spy(self, views, poses, symmetry=None):
        seen.append(symmetry)
        return real(self, views, poses, symmetry=symmetry)

    monkeypatch.setattr(ValidationSelection, "fit", spy)
    spec = "select(estimators=('manifold', 'chance'))"
    job = ModelJob("overview", spec, "golf_ball", 0, (0.0,), 160, 120, 3, 6, (), str(tmp_path))
    (trial,) = run_model_job(job)["trials"]
    assert seen == [get_object("golf_ball").symmetry]
    assert "fit_error" not in trial and all(trial["views"]["valid"])
    choice = trial["selection"]  # the sweep records which candidate answered, and why
    assert choice["selected"] == "chance" and choice["candidates"] == ["manifold", "chance"]
    assert choice["cv_success_5deg"][0] is None and choice["cv_success_5deg"][1] == 1.0
    assert "SIFT" in choice["fit_errors"]["manifold"]
    model = Path(tmp_path) / "experiments" / "models" / f"{model_key(job)}.npz"
    loaded = ValidationSelection.load(model)
    assert loaded.best_name_ == "chance" and "manifold" in loaded.fit_errors_


def test_sweep_reports_one_choice_per_selecting_model():
    """``selections`` keeps one row per (protocol, estimator, object), whatever the number of
    occlusion levels, and none for estimators that select nothing; the printed table names
    the chosen candidate with the cross-validated score that chose it."""
    from scorbot_gym.experiments.aggregate import format_selections, selections

    choice = {"selected": "b", "candidates": ["a", "b"], "cv_success_5deg": [None, 0.75],
              "cv_median_rot_err_deg": [None, 1.5], "fit_errors": {"a": "too few"}}  # fmt: skip
    trials = [
        {"protocol": "p", "estimator": "select(x)", "object": o, "occlusion": occ,
         "selection": choice}
        for o in ("ball", "box") for occ in (0.0, 0.5)
    ] + [{"protocol": "p", "estimator": "manifold", "object": "box", "occlusion": 0.0}]  # fmt: skip
    rows = selections(trials)
    assert [(r["estimator"], r["object"]) for r in rows] == [("select(x)", "ball"),
                                                             ("select(x)", "box")]  # fmt: skip
    assert rows[0]["selected"] == "b" and rows[0]["fit_errors"] == {"a": "too few"}
    table = format_selections(rows).splitlines()
    assert table[0].startswith("select(x) chose") and len(table) == 3
    assert table[1].split() == ["ball", "75.0", "b"]
    assert format_selections([]) == ""
