"""Blob splitters for the clutter pose source, by name: ``"none"``, ``"keypoints"``,
``"distance"`` (:mod:`pose.splitting`).

``manifold_clutter`` takes the connected components of the background-subtraction mask as
blobs; objects that touch in the image share one. A splitter is the stage between segmentation
and recognition that cuts such a blob into one region per object, so that each is recognised
and the target's pose is estimated on its own pixels. An ablation swaps it by name
(``make_pose_source("manifold_clutter", models=..., splitter="keypoints")``) or by passing an
object with ``split(image, components, camera) -> list[pose.splitting.Region]``.
"""

from __future__ import annotations

from typing import Any

from pose.model_set import PoseModelSet
from pose.splitting import (
    DistanceWatershedSplitter,
    KeypointWatershedSplitter,
    SplitMemory,
    WholeComponents,
)
from scorbot_gym.names import SPLITTERS


def make_splitter(splitter: str | Any, models: PoseModelSet | None = None) -> Any:
    """A splitter by name or as is. ``"keypoints"`` is fitted on ``models``'s estimators and
    remembers its splits within an episode (:class:`pose.splitting.SplitMemory`: a component
    that did not change keeps its seeds), because a full split asks one pose model per class
    it finds in the component."""
    if not isinstance(splitter, str):
        if not callable(getattr(splitter, "split", None)):
            raise TypeError(f"{splitter!r} has no split(image, components, camera) method")
        return splitter
    if splitter == "none":
        return WholeComponents()
    if splitter == "distance":
        return DistanceWatershedSplitter()
    if splitter == "keypoints":
        if models is None:
            raise ValueError("the 'keypoints' splitter needs the pose models it assigns to")
        return SplitMemory(KeypointWatershedSplitter().fit(models.estimators))
    raise ValueError(f"unknown splitter {splitter!r}; valid: {', '.join(SPLITTERS)}")
