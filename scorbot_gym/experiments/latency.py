"""Single-thread ``predict`` latency of several fitted pose estimators, measured side by side.

The sweep's ``median_ms`` is taken while two workers share two cores and render views, so it
moves with the machine's load (a whole sweep can come out a third slower than the one before).
A latency target ("``predict`` ≤ 30 ms at 320 × 240 on one thread") needs a quieter figure:
:func:`time_predictions` runs in one process pinned to one core with every thread pool at one
thread, and *interleaves* the estimators view by view (rotating which goes first), so a burst of
load on the machine slows all of them alike and their ratio stays fair. Each view is answered
``repeats`` times and its time is the median of those, which drops one-off stalls (page faults,
an interrupt) without hiding a slow view.
"""

from __future__ import annotations

import os
import time
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np


def pin_to_one_core() -> int:
    """Restrict this process to one CPU core and every thread pool to one thread; returns the
    core. Call before timing (after rendering: the renderer may want its threads)."""
    import cv2
    from threadpoolctl import threadpool_limits

    core = min(os.sched_getaffinity(0))
    os.sched_setaffinity(0, {core})
    cv2.setNumThreads(1)
    threadpool_limits(1)
    return core


def time_predictions(
    estimators: Mapping[str, Any], views: Sequence[Any], repeats: int = 3
) -> dict[str, np.ndarray]:
    """Milliseconds per view for each estimator: ``{name: array (n_views,)}``, each view's
    median over ``repeats`` calls of ``predict(view)``.

    The estimators take turns on every view, the first one rotating from view to view and
    repeat to repeat, so none is systematically measured on a warmer cache or a quieter moment.
    One untimed call per estimator comes first (lazy imports, first-use allocations).
    """
    if isinstance(repeats, bool) or not isinstance(repeats, (int, np.integer)) or repeats < 1:
        raise ValueError(f"repeats must be a positive integer, got {repeats!r}")
    names = list(estimators)
    if not names:
        raise ValueError("estimators must hold at least one fitted estimator, got none")
    if not views:
        raise ValueError("views must hold at least one view to time, got none")
    for name in names:
        estimators[name].predict(views[0])
    ms = np.empty((len(names), repeats, len(views)))
    for r in range(repeats):
        for i, view in enumerate(views):
            start = (i + r) % len(names)
            for k in (*range(start, len(names)), *range(start)):
                t0 = time.perf_counter()
                estimators[names[k]].predict(view)
                ms[k, r, i] = 1e3 * (time.perf_counter() - t0)
    return {name: np.median(ms[k], axis=0) for k, name in enumerate(names)}


def stage_timings(estimator: Any, views: Sequence[Any]) -> dict[str, list[float]]:
    """Milliseconds of each stage the estimator reports in ``PoseEstimate.timings_ms`` (SIFT,
    matching, refinement, ...: where the time goes), one entry per valid answer; empty for an
    estimator that reports none. A separate pass from :func:`time_predictions`: the stage
    clocks are the estimator's own, so they need no interleaving."""
    per_stage: dict[str, list[float]] = {}
    for view in views:
        est = estimator.predict(view)
        if est.valid:
            for stage, ms in getattr(est, "timings_ms", {}).items():
                per_stage.setdefault(stage, []).append(float(ms))
    return per_stage


def summarize_latency(
    per_view_ms: Mapping[str, np.ndarray], reference: str | None = None
) -> list[dict]:
    """One row per estimator: ``n``, ``median_ms``, ``p90_ms``, ``max_ms``, and where
    ``reference`` names one of them, ``ratio_to_reference`` (the median over views of this
    estimator's time over the reference's on the same view: a paired ratio)."""
    if reference is not None and reference not in per_view_ms:
        raise ValueError(f"reference {reference!r} is not among the timed estimators "
                         f"{sorted(per_view_ms)}")  # fmt: skip
    rows = []
    for name, ms in per_view_ms.items():
        ms = np.asarray(ms, float)
        row = {"estimator": name, "n": int(ms.size), "median_ms": round(float(np.median(ms)), 2),
               "p90_ms": round(float(np.percentile(ms, 90)), 2),
               "max_ms": round(float(ms.max()), 2)}  # fmt: skip
        if reference is not None:
            ref = np.asarray(per_view_ms[reference], float)
            if ref.shape != ms.shape:
                raise ValueError(
                    f"{name!r} was timed on {ms.size} views and the reference on {ref.size}; "
                    f"a paired ratio needs the same views"
                )
            row["ratio_to_reference"] = round(float(np.median(ms / ref)), 3)
        rows.append(row)
    return rows
