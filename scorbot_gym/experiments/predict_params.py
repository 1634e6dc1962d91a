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

import multiprocessing as mp
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from functools import partial
from typing import Any

from scorbot_gym.experiments.runners import make_jobs
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
    jobs: int = 1,
    cache_dir: str | None = None,
) -> dict:
    """Run :func:`run_param_job` for every (estimator, object) of ``spec`` in ``jobs`` spawned
    worker processes; returns ``{"spec", "parameter", "values", "trials", "stats"}`` like
    :func:`~scorbot_gym.experiments.runners.run_sweep`."""
    if jobs < 1:
        raise ValueError(f"jobs must be >= 1, got {jobs}")
    values = list(values)
    if not values:
        raise ValueError(f"give at least one value of {param!r}")
    for est_spec in spec.estimator_specs:
        known = est_spec.make().get_params(deep=True)
        if param not in known:
            raise ValueError(
                f"{est_spec} has no parameter {param!r}; it has: {', '.join(sorted(known))}"
            )
    model_jobs = make_jobs(spec, cache_dir)
    work = partial(run_param_job, param=param, values=values)
    t0 = time.perf_counter()
    if jobs == 1 or len(model_jobs) <= 1:
        results = [work(job) for job in model_jobs]
    else:
        ctx = mp.get_context("spawn")
        with ProcessPoolExecutor(max_workers=min(jobs, len(model_jobs)), mp_context=ctx) as pool:
            results = list(pool.map(work, model_jobs))
    stats: dict = {"jobs": len(model_jobs), "wall_s": round(time.perf_counter() - t0, 2)}
    for r in results:
        for k, v in r["stats"].items():
            stats[k] = stats.get(k, 0) + v
    stats["fit_s"] = round(stats.get("fit_s", 0.0), 2)
    return {
        "spec": spec.to_dict(),
        "parameter": param,
        "values": values,
        "trials": [t for r in results for t in r["trials"]],
        "stats": stats,
    }
