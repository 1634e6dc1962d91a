"""Train per-object pose models on rendered views (used by ``scorbot-gym pose train``, the
pose sources and the benchmarks).

Each object gets its own estimator, fitted on a :class:`TrainingSet`: a grid of resting faces x
headings, each at random table positions, plus optionally objects tilted out of a resting pose,
rendered (or read from the cache) from the named camera, and the estimator composition by its
registry name. ``train_models`` trains what it is asked (by default the plain ``manifold`` on
resting poses, as ``scorbot-gym pose train`` always did); the models the closed loop uses by
default (:func:`default_pose_models`) are trained on :data:`IN_LOOP_TRAINING`, chosen by
measurement (``benchmarks/tilted_in_loop.py``): RANSAC PnP on the matched keypoints' 3-D points,
trained on resting and tilted views, answers objects leaning up to 30 degrees where the
homography to the nearest resting view cannot (on five catalogue objects: 96.7 % success@5deg on
tilted views against 15.3 %, 94.0 % on resting views against 97.3 %, about 1.05x the time).
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
import time
import warnings
from collections.abc import Sequence
from concurrent.futures import as_completed
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from pose.manifold.estimator import PoseManifoldEstimator
from pose.model_set import PoseModelSet
from scorbot_gym._progress import ItemProgress

N_POSITIONS = 2  # random table positions per (resting face, heading) of the training grid


@dataclass(frozen=True)
class TrainingSet:
    """What one object's pose model is trained on, and which estimator composition.

    ``estimator``: a :mod:`pose.registry` spec (``"manifold"``, ``"manifold-pnp"``,
    ``"manifold-pnp(keypoints__upscale=2)"``). The views: the resting grid (every resting face x
    every ``yaw_step_deg`` heading x :data:`N_POSITIONS` random table positions; ``n_views`` of
    :func:`train_object` overrides the step) plus ``tilted_views`` random poses tilted out of a
    resting pose by up to ``max_tilt_deg`` (:func:`scorbot_gym.data.protocols.tilted_poses`,
    drawn from the training seed, so never the test poses of seed 1). Its :meth:`to_dict` is part
    of the default models' cache key: another training set never loads a stale entry.
    """

    estimator: str = "manifold"
    yaw_step_deg: float = 10.0
    tilted_views: int = 0
    max_tilt_deg: float = 30.0

    def __post_init__(self) -> None:
        from pose.registry import make_from_spec

        # an unknown name or parameter fails here, in one line
        if not isinstance(make_from_spec(self.estimator), PoseManifoldEstimator):
            raise ValueError(
                f"estimator must be a pose-manifold composition (manifold, manifold-pnp, ...: "
                f"what a PoseModelSet holds), got {self.estimator!r}"
            )
        if not 0 < self.yaw_step_deg <= 360:
            raise ValueError(f"yaw_step_deg must be in (0, 360], got {self.yaw_step_deg}")
        if self.tilted_views < 0:
            raise ValueError(f"tilted_views must be >= 0, got {self.tilted_views}")
        if not 0 < self.max_tilt_deg <= 90:
            raise ValueError(f"max_tilt_deg must be in (0, 90], got {self.max_tilt_deg}")

    def samples(self, n_resting: int, seed: int, n_views: int | None = None) -> list:
        """The training poses of an object with ``n_resting`` resting faces."""
        from scorbot_gym.data.protocols import tilted_poses
        from scorbot_gym.data.views import grid_poses, workspace_bounds

        step = self.yaw_step_deg if n_views is None else _yaw_step(n_views, n_resting)
        grid = grid_poses(n_resting, step, workspace_bounds(), N_POSITIONS, seed)
        if not self.tilted_views:
            return grid
        tilt = np.radians(self.max_tilt_deg)
        return grid + tilted_poses(self.tilted_views, n_resting, seed, tilt)

    def make_estimator(self, seed: int, params: dict | None = None):
        from pose.registry import make_from_spec

        est = make_from_spec(self.estimator).set_params(random_state=seed)
        return est.set_params(**(params or {}))

    def to_dict(self) -> dict:
        return asdict(self)


#: what ``train_models`` trains unless told otherwise: the plain manifold on resting poses
RESTING_TRAINING = TrainingSet()
#: the default in-loop models' training, chosen by ``benchmarks/tilted_in_loop.py``
#: (``models`` and ``models_keep0`` in ``benchmarks/results/tilted_in_loop.json``): PnP from
#: every ratio-test match and the global matches (``ratio+global``), kept wherever it fits at
#: least as well as the matched training view (``keep_margin=0``: a leaning object's tilt is in
#: no training view exactly), trained on the resting grid plus 216 views tilted up to 30 degrees
IN_LOOP_TRAINING = TrainingSet(
    estimator="manifold-pnp(refiner__correspondences='ratio+global', refiner__keep_margin=0.0)",
    tilted_views=216,
)


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
    training: TrainingSet = RESTING_TRAINING,
) -> tuple[dict, dict]:
    """Fit one object's estimator; returns its arrays (picklable across processes) and info.
    ``params`` go to ``set_params``, stage parameters included (``bunches__n_bunches``)."""
    from scorbot_gym.data.views import render_views
    from scorbot_gym.objects import get_object

    spec = get_object(name)
    samples = training.samples(len(spec.resting_quats), seed, n_views)
    est = training.make_estimator(seed, params)
    depth = bool(getattr(est.refiner, "needs_depth", False))  # PnP lifts keypoints to 3-D
    t0 = time.perf_counter()
    views = render_views(
        name, samples, camera, width, height, 0.0, seed, cache_dir, progress, depth
    )
    t1 = time.perf_counter()
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


def _timings(info: dict) -> str:
    return f"{info['views']} views, render {info['render_s']:.0f} s, fit {info['fit_s']:.0f} s"


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
    training: TrainingSet = RESTING_TRAINING,
) -> tuple[PoseModelSet, dict]:
    """One estimator per object (``jobs`` objects in parallel processes)."""
    names = _objects(objects)
    args = [
        (n, n_views, camera, width, height, seed, cache_dir, False, params, training) for n in names
    ]
    t0 = time.perf_counter()
    done: dict[str, tuple[dict, dict]] = {}
    desc = f"training pose models ({camera} {width}x{height})"
    with ItemProgress(desc, len(names), enabled=progress) as bar:  # on stderr, per object
        if min(jobs, len(names)) > 1:
            # Spawned, not forked: a forked child of a process that has rendered (EGL context,
            # Mesa threads) can deadlock on its first render.
            from scorbot_gym.experiments.workers import worker_pool

            with worker_pool(min(jobs, len(names))) as pool:  # die with us, know user objects
                futures = {pool.submit(train_object, *a): a[0] for a in args}
                for future in as_completed(futures):
                    done[futures[future]] = future.result()
                    bar.update(futures[future], _timings(done[futures[future]][1]))
        else:
            for a in args:  # the render bars below the objects' bar, on a terminal only
                done[a[0]] = train_object(*a[:7], bar.interactive, params, training)
                bar.update(a[0], _timings(done[a[0]][1]))
    results = [done[n] for n in names]
    models = PoseModelSet(
        {n: PoseManifoldEstimator.from_arrays(r[0]) for n, r in zip(names, results, strict=True)},
        meta={
            "camera": camera,
            "width": width,
            "height": height,
            "seed": seed,
            "training": training.to_dict(),
        },  # fmt: skip
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


def default_models_path(
    camera: str = "top",
    width: int = 320,
    height: int = 240,
    objects: Sequence[str] | None = None,
    seed: int = 0,
    cache_dir: str | os.PathLike | None = None,
    training: TrainingSet = IN_LOOP_TRAINING,
) -> Path:
    """Where :func:`default_pose_models` caches these models: the file name carries a hash of
    the training configuration (camera, size, objects, seed, :class:`TrainingSet`), the
    rendered scene and the estimator's source."""
    from scorbot_gym.data.views import _scene_fingerprint, default_cache_dir

    payload = {
        "camera": camera,
        "width": width,
        "height": height,
        "objects": _objects(objects),
        "seed": seed,
        "training": training.to_dict(),
        "scene": _scene_fingerprint(),
        "pose": _pose_fingerprint(),
    }
    key = hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()[:24]
    folder = Path(cache_dir or default_cache_dir()) / "models"
    return folder / f"{camera}-{width}x{height}-{key}.npz"


def default_pose_models(
    camera: str = "top",
    width: int = 320,
    height: int = 240,
    objects: Sequence[str] | None = None,
    seed: int = 0,
    cache_dir: str | os.PathLike | None = None,
    jobs: int | None = None,
    progress: bool = True,
    training: TrainingSet = IN_LOOP_TRAINING,
) -> PoseModelSet:
    """The default pose models for ``camera``: trained on first use, then read from the cache.

    They are trained on ``training`` (:data:`IN_LOOP_TRAINING`: resting and tilted views, PnP
    refinement). The cache entry is keyed by the training configuration, the rendered scene and
    the estimator's source (:func:`default_models_path`), so a change to any of them retrains
    instead of serving a stale model; an unreadable entry is discarded (with a warning) and
    retrained. ``jobs=None`` trains one object per core.
    """
    names = _objects(objects)
    path = default_models_path(camera, width, height, names, seed, cache_dir, training)
    if path.is_file():
        try:
            return PoseModelSet.load(path)
        except Exception as exc:  # noqa: BLE001 - any unreadable entry is rebuilt, not fatal
            warnings.warn(f"discarding unreadable cached pose model {path}: {exc}", stacklevel=2)
            path.unlink(missing_ok=True)
    jobs = jobs or min(len(names), os.cpu_count() or 1)
    if progress:  # once per cache: say what, where, and how to do it ahead next time
        print(
            f"training the default pose models for camera {camera!r} ({len(names)} objects, "
            f"{width}x{height}), first use only, cached in {path.parent} "
            "(`scorbot-gym pose train --defaults` builds them ahead)",
            file=sys.stderr,
        )
    models, _ = train_models(
        names, None, camera, width, height, seed, cache_dir, jobs, progress, None, training
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    models.save(path, meta={**models.meta, "cache_key": path.stem.rsplit("-", 1)[-1]})
    return models
