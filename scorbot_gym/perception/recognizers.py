"""Recognisers for the pose sources, by name: ``"flr"`` (silhouettes), ``"appearance"`` and
``"flr+appearance"`` (FLR shortlists three classes, appearance decides among them).

``"flr"`` trains one FLR classifier per camera on silhouettes the simulator renders from the
scene's own ``top`` / ``side`` cameras at the env's image size (objects anywhere in the
workspace, random resting face and heading; cached in the view cache), because silhouettes
from the camera the recogniser will see classify far better than ones from other viewpoints
(see the shape-recognition benchmark). ``"appearance"`` needs no training: it asks each
object's pose model how many inliers it explains (:class:`pose.recognition.AppearanceRecognizer`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from pose.model_set import PoseModelSet
from pose.recognition import (
    AppearanceRecognizer,
    Recognition,
    ShortlistRecognizer,
    SilhouetteRecognizer,
)
from pose.shape.descriptors import block_weights
from pose.shape.flr import FLRClassifier
from scorbot_gym.names import RECOGNIZERS

#: the ``manifold`` source's recogniser by default since 2026-11-27: in the loop it recognised
#: more episodes than FLR's shortlist, most of all tilted objects, whose silhouettes FLR was
#: not fitted on (benchmarks/notes/2026-11-27-closed-loop.md); the clutter sources keep
#: ``"flr+appearance"``, the recogniser their figures were measured with
DEFAULT_RECOGNIZER = "appearance"
#: classes FLR shortlists for appearance to decide among (``"flr+appearance"``)
SHORTLIST_LENGTH = 3
#: FLR settings tuned by the shape-recognition benchmark (ART block weighted 3x)
FLR_PARAMS = {"vigilance": 0.97, "feature_weights": block_weights(art=3.0)}
#: rendered silhouettes per object the FLR recogniser is fitted on (cached with the views)
SILHOUETTES_PER_OBJECT = 120


def train_silhouette_recognizer(
    objects: Sequence[str],
    cameras: Sequence[str],
    width: int,
    height: int,
    n_per_object: int = SILHOUETTES_PER_OBJECT,
    seed: int = 0,
    classifier: Any = None,
) -> SilhouetteRecognizer:
    """An FLR (or ``classifier``) per camera, fitted on rendered scene-camera silhouettes.

    ``n_per_object`` silhouettes per object are drawn over the scene's top and side cameras
    (about half each); ``cameras`` must be among those two.
    """
    from scorbot_gym.data.shapes import render_catalogue_silhouettes, scene_cameras

    valid = [c.name for c in scene_cameras()]
    bad = [c for c in cameras if c not in valid]
    if bad or not cameras:
        raise ValueError(
            f"silhouette recognition cameras must be among {valid}, got {list(cameras)}"
        )
    data = render_catalogue_silhouettes(
        objects, n_per_object, width, height, seed=seed, viewpoints="scene"
    )
    groups = np.asarray(data.groups)
    masks = {c: [m for m, g in zip(data.masks, groups, strict=True) if g == c] for c in cameras}
    labels = {c: np.asarray(data.labels)[groups == c] for c in cameras}
    clf = classifier if classifier is not None else FLRClassifier(**FLR_PARAMS)
    return SilhouetteRecognizer(clf).fit(masks, labels)


def make_recognizer(
    recognizer: str | Any,
    models: PoseModelSet,
    cameras: Sequence[str],
    width: int,
    height: int,
    seed: int = 0,
) -> Any:
    """A recogniser by name for ``models``'s objects, or ``recognizer`` itself."""
    if not isinstance(recognizer, str):
        if not callable(getattr(recognizer, "recognize", None)):
            raise TypeError(f"{recognizer!r} has no recognize() method")
        return recognizer
    if recognizer == "flr":
        return train_silhouette_recognizer(models.object_names, cameras, width, height, seed=seed)
    if recognizer == "appearance":
        return AppearanceRecognizer(models.estimators)
    if recognizer == "flr+appearance":
        flr = train_silhouette_recognizer(models.object_names, cameras, width, height, seed=seed)
        return ShortlistRecognizer(flr, AppearanceRecognizer(models.estimators), SHORTLIST_LENGTH)
    raise ValueError(f"unknown recognizer {recognizer!r}; valid: {', '.join(RECOGNIZERS)}")


class IdentityOnlyRecognizer:
    """A recogniser's answer without the pose estimates it made on the way.

    An appearance recogniser returns the winning class's pose estimate, which the pose source
    then uses instead of estimating again. Where the estimator is swapped for a baseline (the
    rotation-blind ``chance`` arm of :mod:`scorbot_gym.evaluation.compare`) but recognition must
    stay the same, that estimate would smuggle the trained models' pose into the baseline's
    answer: this wrapper keeps the label, costs and margin and drops the estimates.
    """

    def __init__(self, recognizer: Any) -> None:
        if not callable(getattr(recognizer, "recognize", None)):
            raise TypeError(f"{recognizer!r} has no recognize() method")
        self.recognizer = recognizer

    @property
    def reads(self) -> str:
        return getattr(self.recognizer, "reads", "view")

    def recognize(self, *args: Any, **kwargs: Any) -> Recognition:
        result = self.recognizer.recognize(*args, **kwargs)
        return dataclasses.replace(result, estimates={})
