"""What the main job builds on first use: listed, checked (``scorbot-gym doctor``) and built
ahead (``scorbot-gym pose train --defaults``).

``scorbot-gym rollout --pose manifold --recognize`` (and ``compare``'s estimator conditions)
need what is built the first time it is asked for and then read from the cache
(``$SCORBOT_GYM_CACHE``, else ``~/.cache/scorbot-gym``): the default pose models of the pose
camera (:func:`~scorbot_gym.perception.training.default_pose_models`, the minutes-long step)
and, for a recogniser that uses FLR (not the default, appearance, which asks the pose models),
silhouettes of the catalogue rendered from the recognition cameras
(:func:`~scorbot_gym.perception.recognizers.train_silhouette_recognizer`). A user who
knows this can pay the cost when it suits them and see whether it has been paid;
:data:`MAIN_JOB` says what the main job uses (a test checks it against
:class:`~scorbot_gym.evaluation.rollout.RolloutConfig` and the comparison's conditions).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from scorbot_gym.perception.recognizers import DEFAULT_RECOGNIZER, SILHOUETTES_PER_OBJECT
from scorbot_gym.perception.training import IN_LOOP_TRAINING, TrainingSet


@dataclass(frozen=True)
class DefaultModels:
    """The models a pose source with default settings builds on first use.

    ``camera`` / ``width`` / ``height``: the pose camera and image size of the default pose
    models; ``objects`` (``None``: the catalogue) and ``training`` as
    :func:`~scorbot_gym.perception.training.default_pose_models` takes them;
    ``recognizer`` the recogniser (silhouettes are rendered only for one that uses FLR),
    ``recognition_cameras`` the cameras whose silhouettes FLR is fitted on,
    ``silhouettes_per_object`` how many.
    """

    camera: str = "top"
    width: int = 320
    height: int = 240
    objects: tuple[str, ...] | None = None
    training: TrainingSet = field(default=IN_LOOP_TRAINING)
    recognizer: str = DEFAULT_RECOGNIZER
    recognition_cameras: tuple[str, ...] = ("top", "side")
    silhouettes_per_object: int = SILHOUETTES_PER_OBJECT


#: what ``rollout --pose manifold --recognize`` and ``compare --poses manifold`` build
MAIN_JOB = DefaultModels()


@dataclass(frozen=True)
class CacheEntry:
    """One cached thing the main job needs: what it is and where it lives."""

    what: str
    path: Path

    @property
    def present(self) -> bool:
        return self.path.is_file()

    @property
    def size_bytes(self) -> int | None:
        return self.path.stat().st_size if self.present else None


def _names(spec: DefaultModels) -> list[str]:
    from scorbot_gym.perception.training import _objects

    return _objects(spec.objects)


def _recognised(names: list[str]) -> list[str]:
    """The objects, in the order the recogniser renders their silhouettes (that of
    :attr:`pose.model_set.PoseModelSet.object_names`; the order is part of the cache key)."""
    return sorted(names)


def cache_entries(spec: DefaultModels | None = None) -> list[CacheEntry]:
    """Where ``spec``'s (default :data:`MAIN_JOB`'s) pose models and recognition silhouettes
    are (or will be) cached."""
    spec = spec or MAIN_JOB
    from scorbot_gym.data.shapes import silhouettes_path
    from scorbot_gym.perception.training import default_models_path

    names = _names(spec)
    size = f"{spec.width}x{spec.height}"
    models = default_models_path(
        spec.camera, spec.width, spec.height, names, training=spec.training
    )
    silhouettes = silhouettes_path(
        _recognised(names), spec.silhouettes_per_object, spec.width, spec.height, 0, "scene"
    )
    cams = "+".join(spec.recognition_cameras)
    entries = [
        CacheEntry(f"pose models, camera {spec.camera} {size} ({len(names)} objects)", models)
    ]
    if _uses_flr(spec):
        entries.append(CacheEntry(f"recognition silhouettes, cameras {cams} {size}", silhouettes))
    return entries


def _uses_flr(spec: DefaultModels) -> bool:
    """Whether ``spec``'s recogniser is fitted on silhouettes (appearance needs no training)."""
    return "flr" in spec.recognizer


def build(
    spec: DefaultModels | None = None, jobs: int | None = None, progress: bool = True
) -> list[CacheEntry]:
    """Build (or find in the cache) exactly what ``spec`` (default :data:`MAIN_JOB`) needs,
    as the main job would on first use; ``jobs`` objects are trained at a time (default one
    per core). Returns the cache entries, all present."""
    spec = spec or MAIN_JOB
    from scorbot_gym.data.shapes import render_catalogue_silhouettes
    from scorbot_gym.perception.training import default_pose_models

    names = _names(spec)
    default_pose_models(
        spec.camera, spec.width, spec.height, names, jobs=jobs, progress=progress,
        training=spec.training,
    )  # fmt: skip
    if _uses_flr(spec):
        render_catalogue_silhouettes(
            _recognised(names), spec.silhouettes_per_object, spec.width, spec.height, seed=0,
            viewpoints="scene", progress=progress,
        )  # fmt: skip
    return cache_entries(spec)


def _megabytes(n: int) -> str:
    return f"{n / 1e6:.1f} MB"


def status_lines(entries: Sequence[CacheEntry]) -> list[str]:
    """One line per entry: ready (with its size) or missing, and its path."""
    lines = []
    for e in entries:
        state = f"ready, {_megabytes(e.size_bytes)}" if e.present else "missing"
        lines.append(f"  {e.what}: {state}\n    {e.path}")
    return lines
