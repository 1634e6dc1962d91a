"""Where the object is in a camera image: the mask a pose estimator works inside.

A segmenter reads the observation (and the camera's calibration) and returns a boolean mask of
the object's visible pixels, or ``None`` when it finds no object. ``PrivilegedSegmenter`` reads
the simulator's ground-truth segmentation image: for oracle experiments and ablations only,
which is why it marks itself ``privileged``.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from scorbot_gym.perception.base import PerceptionFrame


class Segmenter(Protocol):
    privileged: bool
    #: env image types it reads besides ``"rgb"``
    image_types: tuple[str, ...]

    def required_keys(self, camera: str) -> tuple[str, ...]: ...

    def reset(self, frame: PerceptionFrame, camera: str) -> None: ...

    def segment(self, frame: PerceptionFrame, camera: str) -> np.ndarray | None: ...


class PrivilegedSegmenter:
    """The simulator's own object mask (env image type ``"privileged_segmentation"``)."""

    privileged = True
    image_types = ("privileged_segmentation",)

    def required_keys(self, camera: str) -> tuple[str, ...]:
        return (f"{camera}_privileged_segmentation",)

    def reset(self, frame: PerceptionFrame, camera: str) -> None:
        pass

    def segment(self, frame: PerceptionFrame, camera: str) -> np.ndarray | None:
        mask = np.asarray(frame.observation[f"{camera}_privileged_segmentation"])[..., 0] > 0
        return mask if mask.any() else None
