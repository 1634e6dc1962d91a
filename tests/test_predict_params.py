"""Sweeping a predict-time parameter on one fit gives the full sweep's trials for each value."""

import pytest

from scorbot_gym.experiments import sweep
from scorbot_gym.experiments.predict_params import sweep_predict_param, with_param
from scorbot_gym.experiments.trial import ModelJob, run_model_job

ESTIMATOR = "manifold-pnp(matcher__min_inliers=6)"
PARAM = "refiner__keep_margin"
SIZE = {"objects": ("box",), "width": 160, "height": 120, "test_views": 4, "train_stride": 3}


def test_with_param_writes_the_value_into_the_canonical_spec():
    assert with_param("manifold-pnp", PARAM, 0.0) == "manifold-pnp(refiner__keep_margin=0.0)"
    assert with_param(f"manifold-pnp({PARAM}=3.0)", PARAM, 5.0) == with_param(
        "manifold-pnp", PARAM, 5.0
    )


@pytest.mark.slow
def test_one_fit_answers_like_a_fit_per_value(tmp_path):
    """Each value's trial equals the trial of a sweep that fits the estimator with that value
    (the margin is read at predict time only), and the records aggregate like a sweep's."""
    from scorbot_gym.experiments import aggregate

    spec = sweep("side-turntable", [ESTIMATOR], "0", **SIZE)
    run = sweep_predict_param(spec, PARAM, [0.0, 1e6], cache_dir=str(tmp_path))
    assert run["stats"]["fits"] == 1 and run["stats"]["trials_run"] == 2
    by_label = {t["estimator"]: t for t in run["trials"]}
    assert set(by_label) == {with_param(ESTIMATOR, PARAM, v) for v in (0.0, 1e6)}
    label = with_param(ESTIMATOR, PARAM, 0.0)
    job = ModelJob("side-turntable", label, "box", 0, (0.0,), 160, 120, 4, 3, (), str(tmp_path))
    (full,) = run_model_job(job)["trials"]
    for key in ("rot_err_deg", "valid", "R", "t"):
        assert by_label[label]["views"][key] == full["views"][key]
    # a margin no cost difference reaches keeps every training view's rotation: other answers
    keep_all = by_label[with_param(ESTIMATOR, PARAM, 1e6)]["views"]["R"]
    assert keep_all != full["views"]["R"]
    assert {r["estimator"] for r in aggregate(run["trials"])} == set(by_label)


def test_one_fit_answers_every_value(tmp_path):
    """The fast tier's run of the sweep (the comparison with a fit per value is slow): one fit,
    a trial per value, each labelled with its value and scored on every test view."""
    spec = sweep("side-turntable", [ESTIMATOR], "0", **SIZE)
    run = sweep_predict_param(spec, PARAM, [0.0, 2.0], cache_dir=str(tmp_path))
    assert (run["stats"]["fits"], run["stats"]["trials_run"]) == (1, 2)
    labels = [t["estimator"] for t in run["trials"]]
    assert sorted(labels) == sorted(with_param(ESTIMATOR, PARAM, v) for v in (0.0, 2.0))
    assert all(len(t["views"]["rot_err_deg"]) == SIZE["test_views"] for t in run["trials"])


def test_a_parameter_the_estimator_lacks_is_refused(tmp_path):
    spec = sweep("side-turntable", ["manifold"], "0", **SIZE)
    with pytest.raises(ValueError, match="has no parameter 'refiner__keep_margin'"):
        sweep_predict_param(spec, PARAM, [0.0], cache_dir=str(tmp_path))
    with pytest.raises(ValueError, match="at least one value"):
        sweep_predict_param(spec, PARAM, [], cache_dir=str(tmp_path))
