"""Train per-object pose models on rendered views (used by ``scorbot-gym pose train``, the
pose sources and the benchmarks).

Each object gets its own estimator, fitted on a grid of resting faces x headings, each at random
table positions, rendered (or read from the cache) from the named camera.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from tqdm import tqdm

from pose.manifold.estimator import PoseManifoldEstimator
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
    try:
        est.fit([v.view for v in views], np.array([v.camera_from_object for v in views]))
    except ValueError as err:  # e.g. too few keypoints for the vocabulary: say where
        raise ValueError(
            f"cannot train a pose model of {name!r} from camera {camera!r} at {width}x{height}: "
            f"{err} (the object looks too small or too plain there: use a larger image or a "
            "camera nearer the workspace)"
        ) from err
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
        # Spawned, not forked: a forked child of a process that has rendered (EGL context, Mesa
        # threads) can deadlock on its first render.
        from scorbot_gym.experiments.workers import worker_pool

        with worker_pool(min(jobs, len(names))) as pool:  # die with us, know user objects
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


def _pose_fingerprint() -> str:
    """Hash of the estimator's source (the ``pose`` package) and this module: editing either
    invalidates cached models instead of serving stale ones."""
    import pose

    root = Path(pose.__file__).resolve().parent
    h = hashlib.sha256()
    for f in [Path(__file__).resolve(), *sorted(root.rglob("*.py"))]:
        h.update(f.name.encode() + f.read_bytes())
    return h.hexdigest()[:16]


def default_pose_models(
    camera: str = "top",
    width: int = 320,
    height: int = 240,
    objects: Sequence[str] | None = None,
    seed: int = 0,
    cache_dir: str | os.PathLike | None = None,
    jobs: int | None = None,
    progress: bool = True,
) -> PoseModelSet:
    """The default pose models for ``camera``: trained on first use, then read from the cache.

    The cache entry is keyed by the training configuration, the rendered scene and the
    estimator's source, so a change to any of them retrains instead of serving a stale model; an
    unreadable entry is discarded (with a warning) and retrained. ``jobs=None`` trains one
    object per core.
    """
    from scorbot_gym.data.views import _scene_fingerprint, default_cache_dir

    names = _objects(objects)
    payload = {
        "camera": camera,
        "width": width,
        "height": height,
        "objects": names,
        "seed": seed,
        "scene": _scene_fingerprint(),
        "pose": _pose_fingerprint(),
    }
    key = hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()[:24]
    path = (
        Path(cache_dir or default_cache_dir()) / "models" / f"{camera}-{width}x{height}-{key}.npz"
    )
    if path.is_file():
        try:
            return PoseModelSet.load(path)
        except Exception as exc:  # noqa: BLE001 - any unreadable entry is rebuilt, not fatal
            warnings.warn(f"discarding unreadable cached pose model {path}: {exc}", stacklevel=2)
            path.unlink(missing_ok=True)
    jobs = jobs or min(len(names), os.cpu_count() or 1)
    if progress:
        print(f"training the default pose models for camera {camera!r} (cached in {path.parent})")
    models, _ = train_models(names, None, camera, width, height, seed, cache_dir, jobs, progress)
    path.parent.mkdir(parents=True, exist_ok=True)
    models.save(path, meta={**models.meta, "cache_key": key})
    return models
