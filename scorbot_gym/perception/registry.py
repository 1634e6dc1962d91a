"""One registry of pose sources, by name: ``oracle``, ``noisy_oracle``, ``manifold``, ...
(``constant`` and ``oracle_position``: the image-blind answers, :mod:`.constant`).

An ablation swaps the pose source by name (``make_pose_source("noisy_oracle",
yaw_sigma_deg=10)``) or by passing an object. Users add their own with
:func:`register_pose_source`: a factory returning a :class:`~scorbot_gym.perception.base.
PoseSource`, or a plain function ``frame -> WorldPose`` (wrapped in :class:`FunctionPoseSource`).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from scorbot_gym.perception.base import PerceptionFrame, PoseSource, WorldPose
from scorbot_gym.perception.constant import ConstantPoseSource, true_position_source
from scorbot_gym.perception.oracle import (
    NoisyOraclePoseSource,
    OccludedOraclePoseSource,
    OraclePoseSource,
)


class FunctionPoseSource:
    """A plain function ``frame -> WorldPose`` as a pose source."""

    def __init__(
        self,
        fn: Callable[[PerceptionFrame], WorldPose],
        required_keys: Sequence[str] = (),
        privileged: bool = False,
    ) -> None:
        self.fn, self.required_keys, self.privileged = fn, tuple(required_keys), privileged

    def reset(self, frame: PerceptionFrame, rng: np.random.Generator) -> None:
        pass

    def estimate(self, frame: PerceptionFrame) -> WorldPose:
        return self.fn(frame)


def _model_set_source(**kwargs: Any) -> PoseSource:
    """The pose-manifold source, imported on first use: it pulls in OpenCV's and
    scikit-learn's estimators, which an env run on the oracle never needs (tens of MB)."""
    from scorbot_gym.perception.model_set import ModelSetPoseSource

    return ModelSetPoseSource(**kwargs)


def _clutter_source(**kwargs: Any) -> PoseSource:
    """The pose-manifold source for tables with several objects (blobs split, each recognised,
    the target's pose estimated), imported on first use like ``manifold``."""
    from scorbot_gym.perception.clutter import ClutterPoseSource

    return ClutterPoseSource(**kwargs)


def _blob_choice_source(choice: str) -> Callable[..., PoseSource]:
    """A clutter baseline that takes the ``choice`` blob without recognising any
    (``largest_blob``, ``random_blob``: :mod:`scorbot_gym.perception.blob_choice`)."""

    def make(**kwargs: Any) -> PoseSource:
        from scorbot_gym.perception.blob_choice import BlobChoicePoseSource

        if "choice" in kwargs:
            raise ValueError(
                f"the {choice}_blob source always takes the {choice} blob: drop choice= "
                "(largest_blob and random_blob are the two choices)"
            )
        return BlobChoicePoseSource(choice=choice, **kwargs)

    return make


_REGISTRY: dict[str, Callable[..., Any]] = {
    "oracle": OraclePoseSource,
    "noisy_oracle": NoisyOraclePoseSource,
    "occluded_oracle": OccludedOraclePoseSource,
    "oracle_position": true_position_source,
    "constant": ConstantPoseSource,
    "manifold": _model_set_source,
    "manifold_clutter": _clutter_source,
    "largest_blob": _blob_choice_source("largest"),
    "random_blob": _blob_choice_source("random"),
}


def pose_source_names() -> tuple[str, ...]:
    return tuple(sorted(_REGISTRY))


def register_pose_source(
    name: str, factory: Callable[..., Any], *, overwrite: bool = False
) -> None:
    """Make ``make_pose_source(name, **kwargs)`` call ``factory(**kwargs)``.

    The factory returns a pose source, or a function ``PerceptionFrame -> WorldPose``.
    """
    if not name or not isinstance(name, str):
        raise ValueError(f"a pose source needs a non-empty name, got {name!r}")
    if name in _REGISTRY and not overwrite:
        raise ValueError(f"pose source {name!r} is already registered (pass overwrite=True)")
    if not callable(factory):
        raise TypeError(f"factory for pose source {name!r} must be callable, got {factory!r}")
    _REGISTRY[name] = factory


def make_pose_source(source: str | PoseSource, **kwargs: Any) -> PoseSource:
    """A pose source by registered name (``kwargs`` go to its factory), or ``source`` itself."""
    if not isinstance(source, str):
        if kwargs:
            raise ValueError("keyword arguments are only accepted with a pose source name")
        if not isinstance(source, PoseSource):
            raise TypeError(
                f"{source!r} is not a PoseSource (it needs required_keys, privileged, reset and "
                "estimate)"
            )
        return source
    if source not in _REGISTRY:
        raise ValueError(
            f"unknown pose source {source!r}; registered: {', '.join(pose_source_names())}"
        )
    try:
        made = _REGISTRY[source](**kwargs)
    except TypeError as exc:
        if not _raised_by_the_call(exc):  # a TypeError from inside the source: as it is
            raise
        raise ValueError(f"pose source {source!r} was given the wrong arguments: {exc}") from None
    if not isinstance(made, PoseSource):
        if not callable(made):
            raise TypeError(f"pose source {source!r} is neither a PoseSource nor a callable")
        made = FunctionPoseSource(made)
    if getattr(made, "name", None) is None:
        made.name = source  # how records and summaries refer to it
    with contextlib.suppress(AttributeError):  # how an env's spec records it (see the wrapper)
        made.made_from = (source, dict(kwargs))
    return made


def _raised_by_the_call(exc: TypeError) -> bool:
    """Whether ``exc`` came from calling a factory with arguments it does not take (an unknown
    or missing keyword): Python raises that in the calling frame, which is in this module
    (``make_pose_source``, or a lazy factory here calling its class), before the callee runs."""
    tb = exc.__traceback__
    while tb is not None and tb.tb_next is not None:
        tb = tb.tb_next
    return tb is not None and tb.tb_frame.f_code.co_filename == __file__
