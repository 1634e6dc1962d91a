"""Image-blind pose sources: the same answer whatever the cameras see.

An estimator's figure in the loop means little without the level a source reaches that does not
look: the project reports each arm named for what it is blind to. ``constant`` answers one pose
for every episode (the object resting on its first face at the centre of the region the task
places objects in, heading 0): blind to position and rotation, the floor of the table.
``oracle_position`` answers the true position with that same constant rotation: blind to the
rotation alone, the most a source that gets the position exactly right but ignores the heading
can reach. (The ``manifold`` source with ``estimator="chance"`` is the rotation-blind arm that
takes its position from the image: see :mod:`scorbot_gym.perception.baseline_models`.)

Neither reads an image, so neither can recognise the object: both need its identity given
(``identity="given"``, what a task's command names), from which they take its resting height.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from scorbot_gym.objects import get_object
from scorbot_gym.perception.base import PerceptionFrame, WorldPose
from scorbot_gym.sim.scene import WORKSPACE_X, WORKSPACE_Y
from scorbot_gym.sim.simulation import resting_pose

#: where ``constant`` puts every object: the centre of the region the task draws positions from
WORKSPACE_CENTRE = (sum(WORKSPACE_X) / 2, sum(WORKSPACE_Y) / 2)
POSITIONS = ("centre", "true")


class ConstantPoseSource:
    """One rotation for every object and episode, at a constant or the true position.

    Parameters
    ----------
    position
        ``"centre"``: the centre of the task's placement region (``WORKSPACE_CENTRE``), on the
        table; ``"true"``: the object's true position (the source is then privileged: it
        reads the ground truth, and records say so); or an ``(x, y)`` on the table, metres.
    yaw_deg
        The heading answered, degrees about the vertical (the task draws headings uniformly,
        so any one is as good as another on average).
    resting_index
        The resting face answered (the env places objects on face 0 unless told otherwise).
    """

    required_keys: tuple[str, ...] = ()

    def __init__(
        self,
        position: str | Sequence[float] = "centre",
        yaw_deg: float = 0.0,
        resting_index: int = 0,
    ) -> None:
        if isinstance(position, str):
            if position not in POSITIONS:
                raise ValueError(
                    f"position must be one of {POSITIONS} or an (x, y) in metres, got {position!r}"
                )
            xy = WORKSPACE_CENTRE if position == "centre" else None
        else:
            xy = tuple(float(v) for v in np.ravel(position))
            if len(xy) != 2 or not np.isfinite(xy).all():
                raise ValueError(
                    f"position must be one of {POSITIONS} or a finite (x, y) in metres, "
                    f"got {position!r}"
                )
        if not np.isfinite(yaw_deg):
            raise ValueError(f"yaw_deg must be a finite number of degrees, got {yaw_deg!r}")
        if isinstance(resting_index, bool) or not isinstance(resting_index, (int, np.integer)):
            raise ValueError(f"resting_index must be an int >= 0, got {resting_index!r}")
        if resting_index < 0:
            raise ValueError(f"resting_index must be an int >= 0, got {resting_index}")
        self.position, self.yaw_deg, self.resting_index = position, float(yaw_deg), resting_index
        self._xy = xy
        self.privileged = xy is None  # the true position is read from the ground truth
        self._answers: dict[str, tuple[np.ndarray, np.ndarray]] = {}

    def reset(self, frame: PerceptionFrame, rng: np.random.Generator) -> None:
        self._check_identity(frame)

    def estimate(self, frame: PerceptionFrame) -> WorldPose:
        name = self._check_identity(frame)
        if name not in self._answers:  # the same answer every step: computed once per object
            xy = self._xy if self._xy is not None else (0.0, 0.0)
            self._answers[name] = resting_pose(
                get_object(name), xy, np.radians(self.yaw_deg), self.resting_index
            )
        position, quaternion = (a.copy() for a in self._answers[name])
        if self._xy is None:
            position = np.asarray(frame.truth["position"], float).copy()
        return WorldPose(position, quaternion, True, 1.0, object_name=name)

    def _check_identity(self, frame: PerceptionFrame) -> str:
        """The object's given name; a clear error where it is withheld (nothing to recognise
        it from: the source reads no image)."""
        if frame.object_name is None:
            raise ValueError(
                "an image-blind pose source (constant, oracle_position) reads no image and "
                "cannot recognise the object: give its identity (identity='given', no "
                "--recognize)"
            )
        return frame.object_name


def true_position_source(yaw_deg: float = 0.0, resting_index: int = 0) -> ConstantPoseSource:
    """The ``oracle_position`` source: the true position, a constant rotation."""
    return ConstantPoseSource("true", yaw_deg, resting_index)
