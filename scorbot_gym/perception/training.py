"""Train per-object pose models on rendered views (used by ``scorbot-gym pose train``, the
pose sources and the benchmarks).

Each object gets its own estimator, fitted on a grid of resting faces x headings, each at random
table positions, rendered (or read from the cache) from the named camera.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor

import numpy as np
from tqdm import tqdm

from pose.estimator import PoseManifoldEstimator
from pose.model_set import PoseModelSet

N_POSITIONS = 2  # random table positions per (resting face, heading) of the training grid


def _objects(names: Sequence[str] | None) -> list[str]:
    from scorbot_gym.objects import CATALOGUE, get_object

    if not names:
        return list(CATALOGUE)
    return [get_object(n).name for n in names]  # KeyError lists the valid names


def _yaw_step(n_views: int | None, n_resting: int) -> float:
    """Heading step that gives about ``n_views`` training views per object."""
    if n_views is None:
        return 10.0
    if n_views < n_resting * N_POSITIONS:
        raise ValueError(
            f"--views must be at least {n_resting * N_POSITIONS} for an object with "
            f"{n_resting} resting faces ({N_POSITIONS} positions each), got {n_views}"
        )
    return 360.0 / max(1, n_views // (n_resting * N_POSITIONS))


def train_object(
    name: str,
    n_views: int | None = None,
    camera: str = "top",
    width: int = 320,
    height: int = 240,
    seed: int = 0,
    cache_dir: str | None = None,
    progress: bool = True,
    params: dict | None = None,
) -> tuple[dict, dict]:
    """Fit one object's estimator; returns its arrays (picklable across processes) and info.
    ``params`` go to ``set_params``, stage parameters included (``bunches__n_bunches``)."""
    from scorbot_gym.data.views import grid_poses, render_views, workspace_bounds
    from scorbot_gym.objects import get_object

    spec = get_object(name)
    n_rest = len(spec.resting_quats)
    samples = grid_poses(n_rest, _yaw_step(n_views, n_rest), workspace_bounds(), N_POSITIONS, seed)
    t0 = time.perf_counter()
    views = render_views(name, samples, camera, width, height, 0.0, seed, cache_dir, progress)
    t1 = time.perf_counter()
    est = PoseManifoldEstimator(random_state=seed).set_params(**(params or {}))
    est.fit([v.view for v in views], np.array([v.camera_from_object for v in views]))
    t2 = time.perf_counter()
    info = {"views": len(views), "render_s": t1 - t0, "fit_s": t2 - t1}
    return est.to_arrays(), info


def train_models(
    objects: Sequence[str] | None = None,
    n_views: int | None = None,
    camera: str = "top",
    width: int = 320,
    height: int = 240,
    seed: int = 0,
    cache_dir: str | None = None,
    jobs: int = 1,
    progress: bool = True,
    params: dict | None = None,
) -> tuple[PoseModelSet, dict]:
    """One estimator per object (``jobs`` objects in parallel processes)."""
    names = _objects(objects)
    args = [(n, n_views, camera, width, height, seed, cache_dir, False, params) for n in names]
    t0 = time.perf_counter()
    if min(jobs, len(names)) > 1:
        with ProcessPoolExecutor(max_workers=min(jobs, len(names))) as pool:
            futures = [pool.submit(train_object, *a) for a in args]
            results = [f.result() for f in tqdm(futures, desc="train", disable=not progress)]
    else:
        results = [train_object(*a[:7], progress, params) for a in args]  # bars per object
    models = PoseModelSet(
        {n: PoseManifoldEstimator.from_arrays(r[0]) for n, r in zip(names, results, strict=True)},
        meta={"camera": camera, "width": width, "height": height, "seed": seed},
    )
    info = {n: r[1] for n, r in zip(names, results, strict=True)}
    info["total_s"] = time.perf_counter() - t0
    return models, info
