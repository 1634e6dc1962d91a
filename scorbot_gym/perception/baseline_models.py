"""Baseline pose models for the closed loop, fitted on the views the default models learn from.

The project's evaluation rule puts the chance level (an image-blind answer) and simple
baselines beside every estimator figure. In the closed loop that is an ablation by swapping one
component: the ``manifold`` pose source runs as always (same segmentation, same recognition)
with a model set of a :mod:`pose.registry` baseline in place of the trained pose-manifold models
(``chance``: one constant rotation, the training views' medoid, placed at the silhouette;
``pca-nn``, ``least-squares``, ...). :func:`baseline_models` fits that set on exactly the views
the compared models are trained on (a :class:`~scorbot_gym.perception.training.TrainingSet`,
read from the same render cache), so the two differ in the estimator alone;
:func:`baseline_source_kwargs` adds the recognition of the compared models with their pose
estimates dropped. The closed-loop benchmarks (``RolloutConfig.estimator``,
``benchmarks/tilted_in_loop.py``) and the scripted-vs-learned comparison
(:mod:`scorbot_gym.evaluation.compare`, its ``chance`` pose condition) use it.

It lives apart from :mod:`~scorbot_gym.perception.training` because that module's source is
part of the default models' cache key: a change here must refit the small baseline sets, never
retrain the default models.
"""

from __future__ import annotations

import hashlib
import os
import re
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from pose.model_set import PoseModelSet
from scorbot_gym.perception.training import IN_LOOP_TRAINING, TrainingSet


def baseline_models_path(
    spec: str,
    training: TrainingSet = IN_LOOP_TRAINING,
    objects: Sequence[str] | None = None,
    camera: str = "top",
    width: int = 320,
    height: int = 240,
    seed: int = 0,
    cache_dir: str | os.PathLike | None = None,
) -> Path:
    """Where :func:`baseline_models` caches the ``spec`` set: beside the default models of the
    same training (:func:`~scorbot_gym.perception.training.default_models_path`: camera, size,
    objects, seed, views, scene and estimator source), with the spec and this module's source
    added to the name, so another baseline or another fitting never loads a stale entry."""
    from scorbot_gym.perception.training import _objects, default_models_path

    base = default_models_path(camera, width, height, _objects(objects), seed, cache_dir, training)
    slug = re.sub(r"[^A-Za-z0-9]+", "_", spec).strip("_")
    code = hashlib.sha256(Path(__file__).read_bytes()).hexdigest()[:8]
    return base.with_name(f"{base.stem}-{slug}-{code}.npz")


def _fit_baseline(
    spec: str,
    training: TrainingSet,
    name: str,
    camera: str,
    width: int,
    height: int,
    seed: int,
    cache_dir: str | os.PathLike | None,
) -> dict[str, Any]:
    """One object's ``spec`` estimator fitted on ``training``'s views (a worker's job): the
    rendered views :func:`~scorbot_gym.perception.training.train_object` trains on, read from
    the same cache. Returns its class name and arrays (picklable across processes)."""
    import numpy as np

    from pose.composition import fit_estimator
    from pose.registry import make_from_spec
    from scorbot_gym.data.views import render_views
    from scorbot_gym.objects import get_object

    obj = get_object(name)
    samples = training.samples(len(obj.resting_quats), seed)
    # the same renders as the trained models' (with depth where their refiner lifts keypoints)
    depth = bool(getattr(training.make_estimator(seed).refiner, "needs_depth", False))
    views = render_views(name, samples, camera, width, height, 0.0, seed, cache_dir, False, depth)
    est = make_from_spec(spec)
    poses = np.array([v.camera_from_object for v in views])
    fit_estimator(est, [v.view for v in views], poses, obj.symmetry)
    return {"object": name, "class": type(est).__name__, "arrays": est.to_arrays()}


def baseline_models(
    spec: str,
    training: TrainingSet = IN_LOOP_TRAINING,
    objects: Sequence[str] | None = None,
    jobs: int = 1,
    progress: bool = True,
    camera: str = "top",
    width: int = 320,
    height: int = 240,
    seed: int = 0,
    cache_dir: str | os.PathLike | None = None,
) -> Path:
    """The file of a model set of the ``spec`` estimator (a :mod:`pose.registry` baseline,
    e.g. ``"chance"``), one per object (default: the catalogue), fitted on the views of
    ``training`` from ``camera`` at ``width`` x ``height``: what the ``manifold`` pose source
    runs in place of the trained models for an image-blind or baseline arm.

    Fitted on first use (``jobs`` objects in parallel processes) and cached at
    :func:`baseline_models_path`; an unreadable entry is discarded (with a warning) and fitted
    again. The set's ``meta`` names the estimator and the training it took its views from.
    """
    from pose.composition import load_part
    from pose.registry import make_from_spec
    from scorbot_gym.perception.training import _objects

    make_from_spec(spec)  # an unknown name or parameter fails here, in one line
    if jobs < 1:
        raise ValueError(f"jobs must be >= 1, got {jobs}")
    names = _objects(objects)
    path = baseline_models_path(spec, training, names, camera, width, height, seed, cache_dir)
    if path.is_file():
        try:
            PoseModelSet.load(path)
            return path
        except Exception as exc:  # noqa: BLE001 - any unreadable entry is refitted, not fatal
            warnings.warn(f"discarding unreadable cached baseline set {path}: {exc}", stacklevel=2)
            path.unlink(missing_ok=True)
    if progress:
        print(f"fitting {spec!r} on the views of {training} ({len(names)} objects)", flush=True)
    args = [(spec, training, n, camera, width, height, seed, cache_dir) for n in names]
    if min(jobs, len(names)) > 1:
        from scorbot_gym.experiments.workers import worker_pool

        with worker_pool(min(jobs, len(names))) as pool:  # spawned: die with us, know user objects
            futures = [pool.submit(_fit_baseline, *a) for a in args]
            fitted = [f.result() for f in futures]
    else:
        fitted = [_fit_baseline(*a) for a in args]
    models = PoseModelSet(
        {f["object"]: load_part(f["class"], f["arrays"], "", None) for f in fitted},
        meta={"camera": camera, "width": width, "height": height, "seed": seed,
              "estimator": spec, "views_of": training.to_dict()},
    )  # fmt: skip
    path.parent.mkdir(parents=True, exist_ok=True)
    models.save(path)  # atomic
    return path


def baseline_models_like(
    spec: str, models: PoseModelSet, jobs: int = 1, progress: bool = False
) -> Path:
    """:func:`baseline_models` for ``models``'s objects, training views, camera and seed: the
    ``spec`` set a baseline arm swaps in for ``models`` (fitted once, then read from the cache).
    A benchmark calls this to fit the set before its worker processes start, without building
    the recogniser that :func:`baseline_source_kwargs` adds."""
    meta = models.meta
    return baseline_models(
        spec,
        TrainingSet(**meta["training"]),
        models.object_names,
        jobs,
        progress,
        camera=str(meta["camera"]),
        width=int(meta["width"]),
        height=int(meta["height"]),
        seed=int(meta["seed"]),
    )


def baseline_source_kwargs(
    spec: str,
    models: PoseModelSet,
    recognizer: str | Any | None,
    cameras: Sequence[str],
    jobs: int = 1,
    progress: bool = False,
) -> dict[str, Any]:
    """The ``manifold`` pose source's ``models`` and recognition for a baseline arm: the
    ``spec`` set fitted on ``models``'s objects and training views (:func:`baseline_models`),
    and ``models`` as ``recognition_models`` (with ``recognizer``: ``models``'s own recogniser,
    its pose estimates dropped), so the arm differs from the trained one in the estimator
    alone. With a single object, or ``recognizer=None`` (the identity is given), nothing is
    recognised. ``cameras`` is not read (the source builds the recogniser on its own cameras,
    at its first reset); it stays for the callers."""
    from scorbot_gym.perception.references import load_model_set

    kw: dict[str, Any] = {
        "models": load_model_set(baseline_models_like(spec, models, jobs, progress))
    }
    if recognizer is not None and len(models.object_names) > 1:
        kw.update(recognizer=recognizer, recognition_models=models)
    return kw
