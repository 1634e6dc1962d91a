"""The table-top prior: an object resting on the table touches it.

A pose estimated from one camera is weakest along that camera's line of sight; from the top
camera that is the object's height. Models trained on resting views only could not answer
anything but an object on the table, so the table fixed the height for them. Models that also
answer tilted objects (the default since the tilted views were added) have the full 3-D freedom,
and a few millimetres too high is enough for the fingers to close on the upper edge of a flat
object (banana, marker). The table's height is a public fact of the scene, like the cameras'
calibration, so a pose source may use it.

:class:`TableSupport` refines a valid world-frame estimate whose rotation is within
``snap_deg`` of one of the object's resting poses (about its vertical axis): the rotation
becomes that resting pose at the estimated heading (symmetry-aware: a marker lying on the table
may be estimated at any roll about its axis), and the position slides along the
camera's line of sight (so the object projects where the image put it) until the object's
lowest point is on the table. Estimates further from every resting pose (a tilted object on a
stand or leaning on another) are left as they are, as are those that would have to slide more
than ``max_shift_m``: an object lifted in the hand, or one standing on something else.

:class:`TableSupportMemory` makes the same decision once an episode instead of on every
estimate. Whether an object rests on the table does not change while it is being approached,
but the estimates do: with the arm over the object, the top camera's view of a thin object
degrades and its estimated tilt wanders past ``snap_deg``, so the per-estimate rule lets
through the too-high answers it exists to correct, at the moment of the grasp. The memory
votes on the first clear views (as :class:`pose.recognition.RecognitionMemory` keeps the
identity from them) and then holds the answer: an object decided resting has every later
estimate put on the table (within ``hold_deg`` of a resting pose), one decided not resting
(a tilted object on a stand) has none.
"""

from __future__ import annotations

import dataclasses
import functools
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from pose.camera import CameraModel
from scorbot_gym.perception.base import WorldPose
from scorbot_gym.sim.scene import TABLE_HEIGHT
from scorbot_gym.sim.simulation import mat_to_quat, quat_to_mat


@dataclasses.dataclass(frozen=True)
class TableSupport:
    """Snap near-resting estimates onto the table (see the module docstring).

    Parameters
    ----------
    table_height
        The table top's height in the world frame (m).
    snap_deg
        How far (degrees of tilt) an estimated rotation may be from a resting pose to be taken
        as that resting pose. The default sits between the tilt the default models answer for
        objects at rest (97 % of first estimates under 5 degrees) and for objects on a
        10-degree stand (97 % above); ``benchmarks/README.md`` has the measurement.
    max_shift_m
        The longest slide along the line of sight that is applied; an estimate further from
        the table is left alone.
    """

    table_height: float = TABLE_HEIGHT
    snap_deg: float = 5.0
    max_shift_m: float = 0.02

    def __post_init__(self) -> None:
        if not 0.0 <= self.snap_deg <= 90.0:
            raise ValueError(f"snap_deg must be in [0, 90] degrees, got {self.snap_deg}")
        if self.max_shift_m < 0.0:
            raise ValueError(f"max_shift_m must be >= 0 metres, got {self.max_shift_m}")

    def is_resting(self, pose: WorldPose) -> bool:
        """Whether ``pose`` is valid and within ``snap_deg`` of one of its object's resting
        poses: the estimates :meth:`refine` would take as lying on the table (before the
        ``max_shift_m`` check, which needs the camera)."""
        if not pose.valid or pose.object_name is None:
            return False
        _, resting, symmetries = _object_geometry(pose.object_name)
        return _nearest_rest(pose.rotation, resting, symmetries)[0] <= self.snap_deg

    def reset(self) -> None:
        """Nothing to forget: every estimate is judged on its own."""

    def refine(self, pose: WorldPose, camera: CameraModel) -> WorldPose:
        """``pose`` on the table if it is a resting pose within the limits, else ``pose``.

        The refined pose's ``timings_ms["support"]`` is the time this took and its
        ``details["table_support"]`` the tilt snapped (degrees) and the slide (mm)."""
        if not pose.valid or pose.object_name is None:
            return pose
        t0 = time.perf_counter()
        points, resting, symmetries = _object_geometry(pose.object_name)
        R = pose.rotation
        tilt, k, j = _nearest_rest(R, resting, symmetries)
        if tilt > self.snap_deg:
            return pose
        M = R @ symmetries[j] @ resting[k].T
        yaw = np.arctan2(M[1, 0] - M[0, 1], M[0, 0] + M[1, 1])  # the nearest turn about z
        c, s = np.cos(yaw), np.sin(yaw)
        snapped = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ resting[k]
        centre_z = self.table_height - float((points @ snapped[2]).min())
        eye = camera.world_from_camera[:3, 3]
        p = np.asarray(pose.position, float)
        if abs(p[2] - eye[2]) < 1e-6:  # a line of sight parallel to the table: no slide
            return pose
        position = eye + (centre_z - eye[2]) / (p[2] - eye[2]) * (p - eye)
        shift = float(np.linalg.norm(position - p))
        if shift > self.max_shift_m:
            return pose
        timings = {**pose.timings_ms, "support": (time.perf_counter() - t0) * 1e3}
        details = {
            **pose.details,
            "table_support": {"tilt_deg": tilt, "shift_mm": 1e3 * shift},
        }
        return dataclasses.replace(
            pose,
            position=position,
            quaternion=mat_to_quat(snapped),
            timings_ms=timings,
            details=details,
        )


class TableSupportMemory:
    """The table-top prior decided once an episode, on clear views (see the module docstring).

    Parameters
    ----------
    table
        The per-estimate prior: its ``snap_deg`` is the vote of one clear view (resting or
        not) and the rule applied until the votes are in; its table height and
        ``max_shift_m`` hold throughout (a lifted object is never put back on the table).
    votes
        Clear views to decide on (the majority; a tie is resting).
    hold_deg
        After deciding resting, the largest tilt out of a resting pose that is still put on
        the table: a looser bound than ``table.snap_deg``, since the decision is already made,
        but not so loose that an estimate off by a whole face is snapped to the wrong one.
    """

    def __init__(
        self, table: TableSupport | None = None, votes: int = 3, hold_deg: float = 30.0
    ) -> None:
        self.table = table if table is not None else TableSupport()
        if not isinstance(votes, int) or isinstance(votes, bool) or votes < 1:
            raise ValueError(f"votes must be a positive integer, got {votes!r}")
        if not self.table.snap_deg <= hold_deg <= 90.0:
            raise ValueError(
                f"hold_deg must be in [table.snap_deg, 90] = [{self.table.snap_deg}, 90] "
                f"degrees, got {hold_deg}"
            )
        self.votes = votes
        self.hold_deg = float(hold_deg)
        self._held = dataclasses.replace(self.table, snap_deg=self.hold_deg)
        self.reset()

    def __repr__(self) -> str:
        return (
            f"TableSupportMemory(table={self.table!r}, votes={self.votes}, "
            f"hold_deg={self.hold_deg})"
        )

    @property
    def wants_clear(self) -> bool:
        """Whether :meth:`refine` still counts votes (whether the view was clear matters)."""
        return self.resting is None

    def reset(self) -> None:
        """Forget the last episode's votes and decision."""
        self._votes: list[bool] = []
        self.resting: bool | None = None  # the decision; None until the votes are in

    def refine(self, pose: WorldPose, camera: CameraModel, clear: bool = False) -> WorldPose:
        """``pose`` refined by the decision (by ``table`` while undecided); a valid estimate
        from a clear view (``clear``) is a vote until the decision is made.
        ``details["table_support"]["decision"]`` says which rule applied."""
        if not pose.valid or pose.object_name is None:
            return pose
        if self.resting is None:
            if clear:
                self._votes.append(self.table.is_resting(pose))
                if len(self._votes) >= self.votes:
                    self.resting = 2 * sum(self._votes) >= len(self._votes)
            out, decision = self.table.refine(pose, camera), "undecided"
        elif self.resting:
            out, decision = self._held.refine(pose, camera), "resting"
        else:
            out, decision = pose, "not resting"
        record = {**out.details.get("table_support", {}), "decision": decision}
        return dataclasses.replace(out, details={**out.details, "table_support": record})


#: the ``manifold`` source's prior by default since 2026-11-27 (the clutter sources keep
#: ``"table"``, the prior their figures were measured with)
DEFAULT_SUPPORT = "table_memory"

#: the support priors by name (``scorbot_gym.names.SUPPORTS`` is checked against it)
_SUPPORTS: dict[str, type[TableSupport] | type[TableSupportMemory] | None] = {
    "table": TableSupport,
    "table_memory": TableSupportMemory,
    "none": None,
}


def support_names() -> tuple[str, ...]:
    return tuple(_SUPPORTS)


def make_support(support: TableSupport | TableSupportMemory | str | None) -> Any:
    """A support prior by name (``"table"``: :class:`TableSupport`; ``"table_memory"``:
    :class:`TableSupportMemory`; ``"none"`` or ``None``: estimates stay as the models answer
    them) or the object itself (anything with ``refine(pose, camera)``; ``reset()``, and
    with ``wants_clear`` ``refine``'s ``clear`` keyword, are used where it has them)."""
    if isinstance(support, str):
        if support not in _SUPPORTS:
            raise ValueError(
                f"support must be one of {support_names()} or an object with "
                f"refine(pose, camera), got {support!r}"
            )
        factory = _SUPPORTS[support]
        return None if factory is None else factory()
    if support is None or hasattr(support, "refine"):
        return support
    raise ValueError(
        f"support must be one of {support_names()} or an object with refine(pose, camera), "
        f"got {support!r}"
    )


def refine_pose(
    support: Any, pose: WorldPose, camera: CameraModel, clear: Callable[[], bool]
) -> WorldPose:
    """``support.refine(pose, camera)``; a support that ``wants_clear`` (one still deciding,
    :class:`TableSupportMemory`) is also told whether the view was clear. ``clear`` is asked
    only then: the test dilates the mask, work an estimate that needs no vote does not pay."""
    if getattr(support, "wants_clear", False):
        return support.refine(pose, camera, clear=clear())
    return support.refine(pose, camera)


def reset_support(support: Any) -> None:
    """Start a new episode for a support prior that keeps anything between estimates."""
    if support is not None and callable(getattr(support, "reset", None)):
        support.reset()


def _nearest_rest(
    R: np.ndarray, resting: tuple[np.ndarray, ...], symmetries: np.ndarray
) -> tuple[float, int, int]:
    """``(tilt in degrees, resting pose index, symmetry index)`` of the resting pose nearest
    to the rotation ``R``. ``R @ S = Rz(yaw) @ rest`` for an exact resting pose and a symmetry
    ``S`` of the object (a marker lying on the table may be estimated at any roll about its
    axis): the tilt is the angle between the world z axes of ``R @ S @ rest^T`` and the
    identity."""
    best = (np.inf, 0, 0)
    for k, rest in enumerate(resting):
        cos = np.einsum("i,nij,j->n", R[2], symmetries, rest[2])
        j = int(np.argmax(cos))
        tilt = float(np.degrees(np.arccos(np.clip(cos[j], -1.0, 1.0))))
        best = min(best, (tilt, k, j))
    return best


@functools.lru_cache(maxsize=64)
def hull_points(name: str) -> np.ndarray:
    """The vertices of the object's convex hull (object frame): its silhouette's outline, and
    its lowest point under any rotation."""
    import trimesh

    from scorbot_gym.objects import get_object

    return np.asarray(trimesh.convex.convex_hull(get_object(name).mesh_vertices()).vertices)


@functools.lru_cache(maxsize=64)
def _object_geometry(name: str) -> tuple[np.ndarray, tuple[np.ndarray, ...], np.ndarray]:
    """The object's convex-hull vertices, its resting rotations and its symmetry rotations (a
    continuous one every degree)."""
    from scorbot_gym.objects import get_object

    spec = get_object(name)
    resting = tuple(quat_to_mat(np.asarray(q, float)) for q in spec.resting_quats)
    return hull_points(name), resting, spec.symmetry.rotations()
