"""Sweep a parameter that acts only at ``predict`` time: each model fitted once, the same views
answered under every value.

A decision rule applied after the fit, such as ``PnPRefiner``'s ``keep_margin`` (keep the
training view's rotation unless PnP lowers the MSAC cost by more than that margin), is tuned
by answering the test views under each candidate value. As a full sweep that refits every
model for every value; here each (estimator, object) model is fitted (or read from the sweep's
model cache) once and ``set_params`` changes the value between answers. The records are
ordinary trials, labelled with the estimator's spec with that value written in, so
:func:`~scorbot_gym.experiments.aggregate.aggregate` summarises them and each cell equals the
full sweep's for that spec: the caller vouches that ``fit`` never reads the parameter, and
comparing one value against a full sweep checks it. Nothing is written to the trial cache
(a refitted model is not what these answers came from).
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import partial
from typing import Any

from scorbot_gym.experiments.runners import Runner, run_sweep
from scorbot_gym.experiments.spec import EstimatorSpec, SweepSpec
from scorbot_gym.experiments.trial import (
    ModelJob,
    fitted_or_unfitted,
    trial_record,
    trial_views,
)


def with_param(estimator: str, param: str, value: Any) -> str:
    """The canonical spec of ``estimator`` with ``param=value`` set (replacing any value)."""
    spec = EstimatorSpec.parse(estimator)
    params = dict(spec.params)
    params[param] = value
    return str(EstimatorSpec(spec.name, tuple(sorted(params.items()))))


def run_param_job(job: ModelJob, param: str, values: Sequence[Any]) -> dict:
    """The job's model fitted once, its test views answered at every occlusion level under
    every value of ``param``: ``{"trials": [...], "stats": {...}}``."""
    import cv2

    cv2.setNumThreads(1)  # one worker per core: no nested thread pools
    stats = {"fits": 0, "fit_s": 0.0, "fit_errors": 0, "model_cache_hits": 0, "trials_run": 0}
    est = fitted_or_unfitted(job, stats)
    trials = []
    for occ in job.occlusions:
        views = trial_views(job, occ)
        for value in values:
            if hasattr(est, "set_params"):  # an unfitted stand-in answers nothing either way
                est.set_params(**{param: value})
            trials.append(
                trial_record(job, occ, est, views, with_param(job.estimator, param, value))
            )
            stats["trials_run"] += 1
    return {"trials": trials, "stats": stats}


def sweep_predict_param(
    spec: SweepSpec,
    param: str,
    values: Sequence[Any],
    runner: Runner | None = None,
    cache_dir: str | None = None,
) -> dict:
    """Run :func:`run_param_job` for every (estimator, object) of ``spec`` on ``runner``
    (default: in this process); returns :func:`~scorbot_gym.experiments.runners.run_sweep`'s
    ``{"spec", "trials", "stats"}`` with ``parameter`` and ``values``."""
    values = list(values)
    if not values:
        raise ValueError(f"give at least one value of {param!r}")
    for est_spec in spec.estimator_specs:
        known = est_spec.make().get_params(deep=True)
        if param not in known:
            raise ValueError(
                f"{est_spec} has no parameter {param!r}; it has: {', '.join(sorted(known))}"
            )
    work = partial(run_param_job, param=param, values=values)
    return {**run_sweep(spec, runner, cache_dir, work), "parameter": param, "values": values}
