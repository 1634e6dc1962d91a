"""Where the object is in a camera image: the mask a pose estimator works inside.

A segmenter reads the observation (and the camera's calibration) and returns a boolean mask of
the object's visible pixels, or ``None`` when it finds no object. ``PrivilegedSegmenter`` reads
the simulator's ground-truth segmentation image: for oracle experiments and ablations only,
which is why it marks itself ``privileged``. ``BackgroundSegmenter`` needs no simulator: it
compares the camera image with a reference frame of the empty workspace captured at reset
(the env's ``capture_background=True``) and removes the robot's own pixels, rendered from the
robot's kinematic model at the observed joint angles. ``DepthSegmenter`` takes what rises
above the table plane in a depth image, for a camera that moves (no reference frame there).
Choose one by name with :func:`make_segmenter` (``"privileged"``, ``"background"``,
``"depth"``) or pass an object.
"""

from __future__ import annotations

import time
from typing import Any, Protocol

import numpy as np
from sklearn.base import clone

from pose.segmentation import BackgroundSubtractionSegmenter, HeightAboveTableSegmenter
from scorbot_gym.perception.arm_mask import ArmMaskRenderer
from scorbot_gym.perception.base import PerceptionFrame


class Segmenter(Protocol):
    privileged: bool
    #: env image types it reads besides ``"rgb"``
    image_types: tuple[str, ...]
    #: env keyword arguments it needs (e.g. ``{"capture_background": True}``)
    env_kwargs: dict[str, Any]

    def required_keys(self, camera: str) -> tuple[str, ...]: ...

    def reset(self, frame: PerceptionFrame, camera: str) -> None: ...

    def segment(self, frame: PerceptionFrame, camera: str) -> np.ndarray | None: ...


class PrivilegedSegmenter:
    """The simulator's own object mask (env image type ``"privileged_segmentation"``)."""

    privileged = True
    image_types = ("privileged_segmentation",)
    env_kwargs: dict[str, Any] = {}

    def required_keys(self, camera: str) -> tuple[str, ...]:
        return (f"{camera}_privileged_segmentation",)

    def reset(self, frame: PerceptionFrame, camera: str) -> None:
        pass

    def segment(self, frame: PerceptionFrame, camera: str) -> np.ndarray | None:
        mask = np.asarray(frame.observation[f"{camera}_privileged_segmentation"])[..., 0] > 0
        return mask if mask.any() else None


class _ArmAwareSegmenter:
    """What the non-privileged segmenters share: the arm's mask, rendered from the robot's model
    at the observed joint angles with the camera's public calibration, and the last excluded
    mask per camera (``excluded``), so that a recogniser can tell whether the arm touches the
    silhouette."""

    privileged = False

    def __init__(self, arm: ArmMaskRenderer | None = None) -> None:
        self._arm = arm
        self._excluded: dict[str, np.ndarray] = {}
        self.timings_ms: dict[str, float] = {}

    @property
    def arm(self) -> ArmMaskRenderer:
        if self._arm is None:  # built on first use: it compiles a model and a GL context
            self._arm = ArmMaskRenderer()
        return self._arm

    def _arm_now(self, frame: PerceptionFrame, camera: str) -> np.ndarray:
        obs = frame.observation
        opening = float(np.ravel(obs["gripper_opening"])[0])
        return self.arm.render(frame.cameras[camera], obs["joint_pos"], opening)

    def excluded(self, camera: str) -> np.ndarray | None:
        return self._excluded.get(camera)


class BackgroundSegmenter(_ArmAwareSegmenter):
    """Background subtraction against the reset-time reference frame, minus the robot's pixels.

    At :meth:`reset` each camera's reference frame (``frame.backgrounds[camera]``) fits a
    :class:`pose.segmentation.BackgroundSubtractionSegmenter` (a clone of ``subtractor``) and
    the arm's mask in that frame is rendered once. Each :meth:`segment` renders the arm's mask at
    the observed ``joint_pos`` / ``gripper_opening`` with the camera's public calibration and
    excludes both masks (where the arm is, and where it was when the reference was taken).
    Fixed cameras only: a camera that moved since the reset has no valid reference.

    ``excluded(camera)`` is the last excluded mask, so that a recogniser can tell whether the
    arm touches the silhouette; ``timings_ms`` holds the last call's ``arm_mask`` and
    ``subtract`` times.
    """

    image_types: tuple[str, ...] = ()
    env_kwargs: dict[str, Any] = {"capture_background": True}

    def __init__(
        self,
        subtractor: BackgroundSubtractionSegmenter | None = None,
        arm: ArmMaskRenderer | None = None,
    ) -> None:
        super().__init__(arm)
        self.subtractor = subtractor if subtractor is not None else BackgroundSubtractionSegmenter()
        self._fitted: dict[str, BackgroundSubtractionSegmenter] = {}
        self._reference_arm: dict[str, np.ndarray] = {}

    def required_keys(self, camera: str) -> tuple[str, ...]:
        return ()  # the camera's rgb (read by every source) and proprioception only

    def reset(self, frame: PerceptionFrame, camera: str) -> None:
        ref = frame.backgrounds.get(camera)
        if ref is None:
            raise ValueError(
                f"BackgroundSegmenter needs a reference frame of camera {camera!r}: make the env "
                "with capture_background=True (make_env does this for sources that need it)"
            )
        self._fitted[camera] = clone(self.subtractor).fit(np.asarray(ref["rgb"]))
        self._reference_arm[camera] = self.arm.render(
            frame.cameras[camera], ref["joint_pos"], float(np.ravel(ref["gripper_opening"])[0])
        )
        self._excluded.pop(camera, None)

    def foreground(self, frame: PerceptionFrame, camera: str) -> np.ndarray:
        """Every pixel that differs from the reference frame, the arm's included, ``(H, W)``
        bool: what a calibration from the arm's silhouette compares the rendered arm with."""
        if camera not in self._fitted:
            raise RuntimeError(f"BackgroundSegmenter.foreground before reset for camera {camera!r}")
        return self._fitted[camera].foreground(np.asarray(frame.observation[f"{camera}_rgb"]))

    def segment(self, frame: PerceptionFrame, camera: str) -> np.ndarray | None:
        if camera not in self._fitted:
            raise RuntimeError(f"BackgroundSegmenter.segment before reset for camera {camera!r}")
        obs = frame.observation
        t0 = time.perf_counter()
        arm = self._arm_now(frame, camera)
        excluded = arm | self._reference_arm[camera]
        t1 = time.perf_counter()
        mask = self._fitted[camera].segment(np.asarray(obs[f"{camera}_rgb"]), excluded)
        t2 = time.perf_counter()
        self._excluded[camera] = excluded
        self.timings_ms = {"arm_mask": 1e3 * (t1 - t0), "subtract": 1e3 * (t2 - t1)}
        return mask if mask.any() else None


class DepthSegmenter(_ArmAwareSegmenter):
    """The pixels above the table plane in the camera's depth image, minus the robot's pixels.

    It needs no reference frame, so it also serves a camera that moves with the arm
    (``eye_in_hand``), where background subtraction has no empty workspace to compare with:
    the depth image (env image type ``"depth"``, as from an RGB-D camera) and the camera's
    calibration at this step (:class:`pose.segmentation.HeightAboveTableSegmenter`), with the
    arm's mask rendered from its kinematic model at the observed joint angles.
    """

    image_types: tuple[str, ...] = ("depth",)
    env_kwargs: dict[str, Any] = {}

    def __init__(
        self,
        heights: HeightAboveTableSegmenter | None = None,
        arm: ArmMaskRenderer | None = None,
    ) -> None:
        super().__init__(arm)
        self.heights = heights if heights is not None else HeightAboveTableSegmenter()

    def required_keys(self, camera: str) -> tuple[str, ...]:
        return (f"{camera}_depth",)

    def reset(self, frame: PerceptionFrame, camera: str) -> None:
        self._excluded.pop(camera, None)

    def segment(self, frame: PerceptionFrame, camera: str) -> np.ndarray | None:
        obs = frame.observation
        t0 = time.perf_counter()
        arm = self._arm_now(frame, camera)
        t1 = time.perf_counter()
        mask = self.heights.segment(obs[f"{camera}_depth"], frame.cameras[camera], arm)
        t2 = time.perf_counter()
        self._excluded[camera] = arm
        self.timings_ms = {"arm_mask": 1e3 * (t1 - t0), "height": 1e3 * (t2 - t1)}
        return mask if mask.any() else None


_SEGMENTERS = {
    "privileged": PrivilegedSegmenter,
    "background": BackgroundSegmenter,
    "depth": DepthSegmenter,
}


def segmenter_names() -> tuple[str, ...]:
    return tuple(sorted(_SEGMENTERS))


def make_segmenter(segmenter: str | Segmenter | None = None, **kwargs: Any) -> Segmenter:
    """A segmenter by name (``"privileged"``, ``"background"``, ``"depth"``; ``None``:
    privileged) or as is."""
    if segmenter is None:
        segmenter = "privileged"
    if not isinstance(segmenter, str):
        if kwargs:
            raise ValueError("segmenter keyword arguments are only accepted with a name")
        return segmenter
    if segmenter not in _SEGMENTERS:
        raise ValueError(f"unknown segmenter {segmenter!r}; valid: {', '.join(segmenter_names())}")
    return _SEGMENTERS[segmenter](**kwargs)
