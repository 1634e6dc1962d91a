"""Re-calibrate the fixed cameras from the arm's silhouette while an episode runs.

A 1 degree / 5 mm error in a fixed camera's calibration moves every position it estimates by
about a centimetre, and a grasp planned from that closes its fingers off-centre: the table-top
prior fixes the height along the line of sight, not that. The arm is in every image and its
pose is known from the encoders and its kinematic model (:mod:`scorbot_gym.perception.arm_mask`
renders it with the camera's calibration): where the rendered silhouette and the observed one
disagree, the calibration is off, by an amount the disagreement measures. So the object's
position is in effect measured against the hand's, as endpoint-closed-loop visual servoing does,
and the calibration error cancels.

:class:`ArmCalibration` runs a :class:`pose.calibration.SilhouetteExtrinsicsFilter` per fixed
camera: at each estimate it renders the arm (mask and depth) with the camera as currently
estimated, compares it with the background segmenter's change mask (everything that differs
from the empty workspace) and updates the camera's extrinsics; the pose source then segments,
estimates and converts to the world frame with the re-calibrated camera. It reads images,
proprioception and public calibration only, like the segmenter. Choose it by name with
:func:`make_calibration` (``"arm"``; ``"none"``: the cameras as given).
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any

import numpy as np
from sklearn.base import clone

from pose.calibration import SilhouetteExtrinsicsFilter
from scorbot_gym.perception.base import PerceptionFrame


class ArmCalibration:
    """Per fixed camera, the extrinsics re-estimated from the arm's silhouette each step.

    Parameters
    ----------
    estimator
        The filter every camera gets a clone of (default: a
        :class:`~pose.calibration.SilhouetteExtrinsicsFilter` with its defaults: a prior of
        1 cm and 2 degrees per axis, about ten frames' memory).
    min_correction_m
        The nominal calibration is kept until the estimate would move a point of the
        placement region on the table by more than this; from then on, for the rest of the
        episode, the estimate is used. A correct calibration is thus left alone: the
        silhouette's estimate wanders by a millimetre or so, and a grasp of a thin object can
        lose more to that than it gains.

    The segmenter must offer ``foreground(frame, camera)`` (the change mask against the
    reference frame, arm included) and ``arm`` (its :class:`ArmMaskRenderer`), as
    :class:`~scorbot_gym.perception.segmenters.BackgroundSegmenter` does.
    """

    def __init__(
        self,
        estimator: SilhouetteExtrinsicsFilter | None = None,
        min_correction_m: float = 0.003,
    ) -> None:
        if isinstance(min_correction_m, bool) or not 0 <= min_correction_m < float("inf"):
            raise ValueError(f"min_correction_m must be a number >= 0, got {min_correction_m!r}")
        self.estimator = estimator
        self.min_correction_m = float(min_correction_m)
        self._corrected: set[str] = set()  # cameras whose correction was found to matter
        self._filters: dict[str, SilhouetteExtrinsicsFilter] = {}
        self._reference: dict[str, np.ndarray] = {}

    @staticmethod
    def supports(segmenter: Any) -> bool:
        """Whether ``segmenter`` can show the arm: a change mask against a reference frame
        (``foreground``) and the arm's renderer (``arm``)."""
        return hasattr(segmenter, "foreground") and hasattr(segmenter, "arm")

    @staticmethod
    def check_segmenter(segmenter: Any) -> None:
        """A one-line error unless ``segmenter`` can show the arm (a reference-frame one)."""
        if not ArmCalibration.supports(segmenter):
            raise ValueError(
                "calibration='arm' needs a segmenter that compares with a reference frame and "
                f"renders the arm (segmenter='background'), got {type(segmenter).__name__}"
            )

    def reset(self, frame: PerceptionFrame, cameras: tuple[str, ...], segmenter: Any) -> None:
        """Start every camera of ``cameras`` that has a reference frame from its nominal
        calibration; the arm where the reference frame shows it is masked out of the search
        (the change mask is not the arm's there)."""
        self._filters, self._reference = {}, {}
        self._corrected = set()
        template = self.estimator if self.estimator is not None else SilhouetteExtrinsicsFilter()
        for cam in cameras:
            ref = frame.backgrounds.get(cam)
            if ref is None:
                continue
            self._filters[cam] = clone(template).reset(frame.cameras[cam])
            opening = float(np.ravel(ref["gripper_opening"])[0])
            self._reference[cam] = segmenter.arm.render(
                frame.cameras[cam], ref["joint_pos"], opening
            )

    def cameras(self) -> dict[str, Any]:
        """The cameras as currently estimated, by name (each nominal until its correction
        matters, see ``min_correction_m``)."""
        return {
            cam: f.camera if cam in self._corrected else f.nominal_
            for cam, f in self._filters.items()
        }

    def update(
        self, frame: PerceptionFrame, segmenter: Any, at: np.ndarray | None = None
    ) -> PerceptionFrame:
        """Take this step's images into every camera's estimate; ``frame`` with the cameras
        re-calibrated. ``at``: the world point (3,) where the correction matters, the
        object's last estimated position (``None``: not known yet; the placement region is
        used)."""
        points = _region_points() if at is None else np.asarray(at, float).reshape(1, 3)
        obs = frame.observation
        opening = float(np.ravel(obs["gripper_opening"])[0])
        for cam, f in self._filters.items():
            mask, depth = segmenter.arm.render_with_depth(f.camera, obs["joint_pos"], opening)
            image = np.asarray(obs[f"{cam}_rgb"])
            f.update(mask, depth, segmenter.foreground(frame, cam), image, self._reference[cam])
            if cam not in self._corrected and (
                _shift(f.nominal_, f.camera, points) > self.min_correction_m
            ):
                self._corrected.add(cam)
        return dataclasses.replace(frame, cameras={**frame.cameras, **self.cameras()})


@functools.cache
def _region_points() -> np.ndarray:
    """The placement region's corners and centre on the table top (world, m)."""
    from scorbot_gym.sim.scene import TABLE_HEIGHT, WORKSPACE_X, WORKSPACE_Y

    xs, ys = (*WORKSPACE_X, sum(WORKSPACE_X) / 2), (*WORKSPACE_Y, sum(WORKSPACE_Y) / 2)
    points = np.array([(x, y, TABLE_HEIGHT) for x in xs for y in ys])
    points.flags.writeable = False
    return points


def _shift(nominal: Any, estimate: Any, points: np.ndarray) -> float:
    """How far (m) ``estimate`` moves the farthest of ``points`` (world, each seen on the
    horizontal plane at its own height) from where ``nominal`` puts the same pixels."""
    origin, d = estimate.ray(nominal.project(points))
    moved = origin + ((points[:, 2] - origin[2]) / d[:, 2])[:, None] * d
    return float(np.linalg.norm(moved - points, axis=1).max())


#: what ``ModelSetPoseSource`` (pose ``manifold``) uses unless told otherwise, where its
#: segmenter can show the arm (:func:`default_calibration`)
DEFAULT_CALIBRATION = "arm"

#: name -> factory (``None``: the cameras as given); the command line's choices are
#: :data:`scorbot_gym.names.CALIBRATIONS`, checked against these by the tests
_CALIBRATIONS: dict[str, Any] = {"none": None, "arm": ArmCalibration}


def calibration_names() -> tuple[str, ...]:
    return tuple(_CALIBRATIONS)


def default_calibration(segmenter: Any) -> str:
    """:data:`DEFAULT_CALIBRATION` where ``segmenter`` can show the arm (a reference-frame
    segmenter), else ``"none"``: the privileged and depth segmenters keep the cameras as
    given."""
    return DEFAULT_CALIBRATION if ArmCalibration.supports(segmenter) else "none"


def make_calibration(calibration: str | ArmCalibration | None) -> ArmCalibration | None:
    """A calibration by name (``"arm"``; ``"none"`` or ``None``: the cameras as given) or the
    object itself (anything with ``reset`` and ``update``)."""
    name = "none" if calibration is None else calibration
    if isinstance(name, str) and name in _CALIBRATIONS:
        factory = _CALIBRATIONS[name]
        return None if factory is None else factory()
    if not isinstance(name, str) and hasattr(name, "reset") and hasattr(name, "update"):
        return calibration
    raise ValueError(
        f"calibration must be one of {', '.join(_CALIBRATIONS)} or an object with reset and "
        f"update, got {calibration!r}"
    )
