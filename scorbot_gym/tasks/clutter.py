"""Tables with several objects: the one placer of target + distractors, and what distractors add
to an episode's outcome (a non-target lifted, distractors knocked over).

The target is placed first, exactly as on an uncluttered table (:meth:`GraspTask.place_object`,
the same draws from the episode's generator); optionally it is then propped on a stand
(a plate inclined by ``tilt_deg`` with a lip at its lower edge) so it rests tilted out of its
resting pose. Distractors are drawn near it (gaps of a few centimetres, so they occlude each
other and the target from the side and overview cameras), each in one of its resting poses, with
footprints (convex hulls of the projected mesh, grown by a clearance) that do not overlap. The
scene then settles for a moment under physics; a layout where two objects still interpenetrate
is drawn again. Every random choice comes from the episode's generator.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from scorbot_gym.robot import Robot
from scorbot_gym.sim.simulation import Simulation, quat_mul, quat_to_mat
from scorbot_gym.tasks.grasp import GraspTask

#: distractors may lie this far (m) outside the target's workspace: still inside the top view
CLUTTER_MARGIN = 0.07
CLEARANCE = 0.004  # m between footprints
GAP_RANGE = (0.03, 0.15)  # distance (m) of a distractor's centre from the target's
SETTLE_TIME = 0.3  # s of physics after placement, arm at home
PENETRATION_TOL = 0.002  # m; deeper contacts between two objects after settling: drawn again
_RES = 0.001  # m per pixel of the footprint raster
_LAYOUT_TRIES = 20
_TRIES_PER_RING = 5  # failed layouts before the ring of distractors widens
_RING_GROWTH = 0.25  # its outer radius grows by this share of GAP_RANGE's each time
_CANDIDATE_TRIES = 100


@dataclass
class PlacedObject:
    """One object on the table: its role and where it came to rest."""

    name: str
    role: str  # "target" or "distractor"
    up_axis: np.ndarray  # object-frame axis pointing up in its nominal resting pose
    rest_pos: np.ndarray = field(default_factory=lambda: np.zeros(3))
    rest_up: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))


def _axis_angle_quat(axis: np.ndarray, angle: float) -> np.ndarray:
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    return np.r_[np.cos(angle / 2), np.sin(angle / 2) * axis]


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b), -1.0, 1.0))))


class ClutterTask:
    """Target + distractors on one table (a :class:`~scorbot_gym.sim.simulation.Simulation`
    built with several objects), composed with the :class:`GraspTask` that scores the target.

    ``lift_height``: a distractor held between both fingers this far (m) above where it rested
    is a ``wrong_object`` pick. ``knock_deg``: a distractor whose up axis turned this far from
    where it rested (or that fell off the table) is knocked over.
    """

    def __init__(
        self,
        sim: Simulation,
        robot: Robot,
        task: GraspTask,
        tilt_deg: float = 0.0,
        lift_height: float = 0.02,
        knock_deg: float = 30.0,
    ) -> None:
        self.sim, self.robot, self.task = sim, robot, task
        self.tilt_deg, self.lift_height, self.knock_deg = tilt_deg, lift_height, knock_deg
        self.placed: dict[str, PlacedObject] = {}
        self.wrong_object = False
        self._distractor_geoms = np.zeros(0, int)
        (x0, x1), (y0, y1) = sim.workspace_xy_bounds
        self._lo = np.array([x0 - CLUTTER_MARGIN, y0 - CLUTTER_MARGIN])
        self._hi = np.array([x1 + CLUTTER_MARGIN, y1 + CLUTTER_MARGIN])
        size = np.ceil((self._hi - self._lo) / _RES).astype(int)
        self._shape = (int(size[1]), int(size[0]))  # raster rows = y, columns = x

    # --- placement -------------------------------------------------------------------------
    def place(
        self,
        rng: np.random.Generator,
        target: str,
        distractors: Sequence[str],
        resting_index: int = 0,
    ) -> None:
        """Put ``target`` (already placed by the grasp task) and ``distractors`` on the table;
        the scene is left settled, the grasp task's rest position updated."""
        sim = self.sim
        pos, quat = sim.pose_of(target)
        up = quat_to_mat(sim.objects[target].spec.resting_quats[resting_index]).T[:, 2]
        if self.tilt_deg > 0:
            target_hull = self._prop(rng, target, pos, quat)
        else:
            target_hull = self._hull(target, pos, quat, inside=False)
        target_state = sim.data.qpos[sim.objects[target].qpos].copy()
        for attempt in range(_LAYOUT_TRIES):
            # a ring too crowded for every distractor (a large target, or one near the edge of
            # the workspace) widens every few failed layouts instead of failing the reset
            spread = 1.0 + _RING_GROWTH * (attempt // _TRIES_PER_RING)
            gaps = (GAP_RANGE[0], GAP_RANGE[1] * spread)
            poses = self._draw_layout(rng, target_hull, distractors, sim.pose_of(target)[0], gaps)
            if poses is None:
                continue
            sim.data.qpos[sim.objects[target].qpos] = target_state
            sim.data.qvel[sim.objects[target].qvel] = 0.0
            for name, (p, q, _) in poses.items():
                sim.unpark(name)
                sim.set_pose_of(name, p, q)
            sim.forward()
            sim.step(max(1, round(SETTLE_TIME / sim.timestep)))
            if not self._interpenetrating([target, *poses]):
                break  # (otherwise the next layout puts the same objects elsewhere)
        else:
            raise RuntimeError(
                f"could not place {len(distractors)} distractors around {target!r} without "
                f"interpenetration in {_LAYOUT_TRIES} layouts; use fewer distractors"
            )
        sim.data.qvel[:] = 0.0
        sim.forward()
        self.placed = {target: PlacedObject(target, "target", up)}
        for name in distractors:
            rest = sim.objects[name].spec.resting_quats[poses[name][2]]
            self.placed[name] = PlacedObject(name, "distractor", quat_to_mat(rest).T[:, 2])
        for obj in self.placed.values():
            p, q = sim.pose_of(obj.name)
            obj.rest_pos, obj.rest_up = p, quat_to_mat(q) @ obj.up_axis
        self.task.state.rest_pos = self.placed[target].rest_pos.copy()
        geoms = [sim.objects[n].geoms for n in distractors]
        self._distractor_geoms = np.concatenate(geoms) if geoms else np.zeros(0, int)
        self.wrong_object = False

    def _draw_layout(
        self,
        rng: np.random.Generator,
        target_hull: np.ndarray,
        distractors: Sequence[str],
        target_pos: np.ndarray,
        gaps: tuple[float, float] = GAP_RANGE,
    ) -> dict[str, tuple[np.ndarray, np.ndarray, int]] | None:
        """Poses ``{name: (pos, quat, resting index)}`` with non-overlapping footprints, each
        centre ``gaps`` (m) from the target's."""
        occupied = np.zeros(self._shape, np.uint8)
        self._fill(occupied, target_hull, grow=True)
        poses: dict[str, tuple[np.ndarray, np.ndarray, int]] = {}
        for name in distractors:
            rests = len(self.sim.objects[name].spec.resting_quats)
            for _ in range(_CANDIDATE_TRIES):
                rest = int(rng.integers(rests))
                yaw = float(rng.uniform(-np.pi, np.pi))
                r, a = rng.uniform(*gaps), rng.uniform(-np.pi, np.pi)
                xy = target_pos[:2] + r * np.array([np.cos(a), np.sin(a)])
                p, q = self.sim.resting_pose(xy, yaw, rest, name=name)
                hull = self._hull(name, p, q)
                if hull is None:
                    continue
                mask = np.zeros(self._shape, np.uint8)
                self._fill(mask, hull, grow=False)
                if not (mask & occupied).any():
                    self._fill(occupied, hull, grow=True)
                    poses[name] = (p, q, rest)
                    break
            else:
                return None
        return poses

    def _hull(
        self, name: str, pos: np.ndarray, quat: np.ndarray, inside: bool = True
    ) -> np.ndarray | None:
        """The footprint's convex hull in raster pixels; None if ``inside`` and it leaves the
        clutter area (the target may overhang it: its centre is in the workspace)."""
        v = self.sim.objects[name].spec.mesh_vertices() @ quat_to_mat(quat).T + pos
        return self._hull_of(v[:, :2], inside)

    def _hull_of(self, xy: np.ndarray, inside: bool = True) -> np.ndarray | None:
        if inside and ((xy.min(0) < self._lo).any() or (xy.max(0) > self._hi).any()):
            return None
        px = np.round((xy - self._lo) / _RES).astype(np.int32)
        return cv2.convexHull(px)

    def _fill(self, raster: np.ndarray, hull: np.ndarray, grow: bool) -> None:
        cv2.fillConvexPoly(raster, hull, 1)
        if grow:
            cv2.polylines(raster, [hull], True, 1, thickness=2 * round(CLEARANCE / _RES) + 1)

    def _prop(
        self, rng: np.random.Generator, target: str, pos: np.ndarray, quat: np.ndarray
    ) -> np.ndarray:
        """Tilt the target by ``tilt_deg`` onto the stand (downhill heading drawn); returns the
        footprint hull of target and stand."""
        sim = self.sim
        theta = np.radians(self.tilt_deg)
        phi = float(rng.uniform(-np.pi, np.pi))
        tilt = _axis_angle_quat(np.array([-np.sin(phi), np.cos(phi), 0.0]), theta)
        plate_quat = quat_mul(tilt, np.array([np.cos(phi / 2), 0.0, 0.0, np.sin(phi / 2)]))
        downhill, across, normal = quat_to_mat(plate_quat).T  # the plate's axes in the world
        obj_quat = quat_mul(tilt, quat)
        verts = sim.objects[target].spec.mesh_vertices() @ quat_to_mat(obj_quat).T
        u, w = verts @ downhill, verts @ across
        # The plate reaches 1 cm uphill of the object and 1 mm short of it downhill, where the
        # lip stands; its downhill edge rests on the table.
        lo, hi = u.min() - 0.01, u.max() + 0.001
        half = ((hi - lo) / 2, float(np.abs(w).max()) + 0.01)
        thick = 0.004
        anchor = np.array([pos[0], pos[1], sim.table_height + thick + hi * np.sin(theta)])
        centre = anchor + (lo + hi) / 2 * downhill
        # A lip half the object's height: a tall object leans on it instead of toppling over it.
        height = float(np.ptp(verts @ normal))
        sim.set_support(centre - thick * normal, plate_quat, half, lip=max(0.012, height / 2))
        origin = anchor + (5e-4 - (verts @ normal).min()) * normal
        sim.set_pose_of(target, origin, obj_quat)
        sim.forward()
        corners = np.array([[sx * (half[0] + 0.008), sy * half[1], 0.0] for sx in (-1, 1)
                            for sy in (-1, 1)])  # fmt: skip
        plate_xy = (corners @ quat_to_mat(plate_quat).T + centre)[:, :2]
        return self._hull_of(np.vstack([(verts + origin)[:, :2], plate_xy]), inside=False)

    def _interpenetrating(self, names: Sequence[str]) -> bool:
        d, m = self.sim.data, self.sim.model
        body = {self.sim.objects[n].body for n in names}
        for c in d.contact[: d.ncon]:
            b1, b2 = m.geom_bodyid[c.geom[0]], m.geom_bodyid[c.geom[1]]
            if b1 in body and b2 in body and b1 != b2 and c.dist < -PENETRATION_TOL:
                return True
        return False

    # --- per step --------------------------------------------------------------------------
    def update(self) -> None:
        """Note a non-target held between both fingers and lifted (``wrong_object``)."""
        if self.wrong_object or not len(self._distractor_geoms):
            return
        left, right, _ = self.robot.contacts_with(self._distractor_geoms)
        if not (left and right):
            return
        for obj in self.placed.values():
            if obj.role != "distractor":
                continue
            lifted = self.sim.pose_of(obj.name)[0][2] - obj.rest_pos[2] >= self.lift_height
            if lifted and all(self.robot.contacts_with(self.sim.objects[obj.name].geoms)[:2]):
                self.wrong_object = True

    def knocked_over(self, name: str) -> bool:
        obj = self.placed[name]
        pos, quat = self.sim.pose_of(name)
        fell = pos[2] < self.sim.table_height - 0.05
        return fell or _angle_deg(quat_to_mat(quat) @ obj.up_axis, obj.rest_up) > self.knock_deg

    def info(self) -> dict:
        """Ground truth of every object on the table, for scoring only."""
        objects = {}
        for obj in self.placed.values():
            pos, quat = self.sim.pose_of(obj.name)
            up = quat_to_mat(quat) @ obj.up_axis
            objects[obj.name] = {
                "role": obj.role,
                "position": pos,
                "quaternion": quat,
                "tilt_deg": _angle_deg(up, np.array([0.0, 0.0, 1.0])),
                "knocked_over": obj.role == "distractor" and self.knocked_over(obj.name),
            }
        return {
            "objects": objects,
            "wrong_object": self.wrong_object,
            "distractors_knocked_over": sum(o["knocked_over"] for o in objects.values()),
        }


def slide_into_contact(
    sim: Simulation, mover: str, still: str, reach: float = 0.2, gap: float = 0.002
) -> bool:
    """Slide ``mover`` on the table straight toward ``still`` until their geoms touch, then
    back it off ``gap`` metres: two objects that touch in the cameras' images without
    interpenetrating (the scene the blob splitter and the clutter protocol are tested on).
    False, with ``mover`` left at the end of its path, where it never reaches ``still``."""
    p, q = sim.pose_of(mover)
    u = sim.pose_of(still)[0][:2] - p[:2]
    u /= np.linalg.norm(u)
    mover_geoms, still_geoms = set(sim.objects[mover].geoms), set(sim.objects[still].geoms)
    for s in np.linspace(0.0, reach, int(round(reach / 0.001)) + 1):
        sim.set_pose_of(mover, np.r_[p[:2] + s * u, p[2]], q)
        sim.forward()
        pairs = {(int(c.geom[0]), int(c.geom[1])) for c in sim.data.contact[: sim.data.ncon]}
        if any({a, b} & mover_geoms and {a, b} & still_geoms for a, b in pairs):
            sim.set_pose_of(mover, np.r_[p[:2] + (s - gap) * u, p[2]], q)
            sim.forward()
            return True
    return False
