"""Inputs and outputs of the pose estimator: a camera view in, a pose estimate out."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from pose.camera import CameraModel


@dataclass(frozen=True)
class View:
    """One image of one object from a calibrated camera.

    ``image`` is ``HxWx3`` RGB or ``HxW`` grey ``uint8``; ``mask`` (optional, ``HxW`` bool) marks
    the object's visible pixels; ``object_name`` selects the model when a model set holds several;
    ``depth`` (optional, ``HxW`` float, metres along the optical axis, 0 where unknown) is what
    estimators that lift keypoints to 3-D (PnP) train on.
    """

    image: np.ndarray
    camera: CameraModel
    mask: np.ndarray | None = None
    object_name: str | None = None
    depth: np.ndarray | None = None

    def __post_init__(self) -> None:
        img = np.asarray(self.image)
        if img.dtype != np.uint8:
            raise ValueError(f"image must be uint8, got dtype {img.dtype}")
        if img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] not in (1, 3)):
            raise ValueError(f"image must be HxW or HxWx3, got shape {img.shape}")
        h, w = img.shape[:2]
        if (w, h) != (self.camera.width, self.camera.height):
            raise ValueError(
                f"image is {w}x{h} but the camera model is {self.camera.width}x{self.camera.height}"
            )
        if self.mask is not None and np.shape(self.mask) != (h, w):
            raise ValueError(f"mask must have shape {(h, w)}, got {np.shape(self.mask)}")
        if self.depth is not None and np.shape(self.depth) != (h, w):
            raise ValueError(f"depth must have shape {(h, w)}, got {np.shape(self.depth)}")


@dataclass
class PoseEstimate:
    """Object pose in the camera frame (OpenCV axes, metres), with diagnostics.

    ``rotation``/``translation`` are the estimator's answer (refined when enabled);
    ``rotation_coarse`` is the pure manifold-regressor rotation and ``translation_regressed`` the
    regressed position, both kept for ablations. ``valid=False`` means no pose could be estimated
    (``reason`` says why); the arrays are then NaN.
    """

    rotation: np.ndarray
    translation: np.ndarray
    confidence: float
    valid: bool
    timings_ms: dict[str, float] = field(default_factory=dict)
    rotation_coarse: np.ndarray = field(default_factory=lambda: np.full((3, 3), np.nan))
    translation_regressed: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    n_keypoints: int = 0
    n_inliers: int = 0
    reason: str = ""

    @classmethod
    def invalid(cls, reason: str, timings_ms: dict[str, float], n_keypoints: int = 0):
        return cls(
            rotation=np.full((3, 3), np.nan),
            translation=np.full(3, np.nan),
            confidence=0.0,
            valid=False,
            timings_ms=timings_ms,
            n_keypoints=n_keypoints,
            reason=reason,
        )


def predict_each(
    predict_one: Callable[[View], PoseEstimate], view: View | Sequence[View]
) -> PoseEstimate | list[PoseEstimate]:
    """``predict_one(view)`` for one view, a list of its answers for a sequence of views: the
    batch ``predict`` of the compositions and the manifold estimator, with one message for
    anything else."""
    if isinstance(view, View):
        return predict_one(view)
    if isinstance(view, (str, bytes)) or not isinstance(view, Sequence):
        raise ValueError(
            f"predict expects a pose.view.View or a sequence of them, got {type(view).__name__}"
        )
    if not all(isinstance(v, View) for v in view):
        raise ValueError("predict expects pose.view.View objects in the sequence")
    return [predict_one(v) for v in view]
