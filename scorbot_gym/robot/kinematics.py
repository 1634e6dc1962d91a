"""Kinematics of the SCORBOT arm on its own model: FK, IK and the gripper's closing direction.

Policies need the arm's kinematics to turn a target pose into joint angles, but must not reach
into a running environment (in a subprocess vector env there is none to reach). So this model
compiles the arm's MJCF alone, mounted where the scene mounts it, and keeps its own MuJoCo data:
it is the public, documented kinematic description of the robot, the same chain the simulator
uses, and it is cheap to build (a few milliseconds).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from scorbot_gym import _gl
from scorbot_gym.sim.arm import ARM_JOINTS, GRIPPER_MAX_OPENING, JOINT_RANGES_DEG, build_arm

mjcf = _gl.import_mjcf()  # dm_control with its own renderer off (see _gl)

JOINT_LOW = np.deg2rad([JOINT_RANGES_DEG[j][0] for j in ARM_JOINTS])
JOINT_HIGH = np.deg2rad([JOINT_RANGES_DEG[j][1] for j in ARM_JOINTS])
ARM_PREFIX = "scorbot/"
_LOW4, _HIGH4 = JOINT_LOW[:4], JOINT_HIGH[:4]  # the joints IK moves
_LOW4_LIST, _HIGH4_LIST = _LOW4.tolist(), _HIGH4.tolist()  # floats for the closed form
_ROLL_LOW, _ROLL_HIGH = float(JOINT_LOW[4]), float(JOINT_HIGH[4])
_EYE4 = np.eye(4)
_EYE4.flags.writeable = False


def _as_slice(index: np.ndarray) -> slice | np.ndarray:
    """``index`` as the equal slice when its entries run consecutively, else as it is."""
    start = int(index[0])
    consecutive = np.array_equal(index, np.arange(start, start + len(index)))
    return slice(start, start + len(index)) if consecutive else index


try:  # the LAPACK gufunc that np.linalg.solve calls
    from numpy.linalg._umath_linalg import solve1 as _lapack_solve1
except ImportError:  # a numpy without it: the public function, the same result
    _lapack_solve1 = None


def _solve(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.linalg.solve(a, b)`` for one square ``a`` and vector ``b`` without its ~4 us of
    argument checks (IK solves a 4x4 a few times per env step; ``a`` is J J^T + damping^2 I,
    never singular)."""
    if _lapack_solve1 is None:
        return np.linalg.solve(a, b)
    return _lapack_solve1(a, b, signature="dd->d")


def wrap_half_turn(angle: float) -> float:
    """Wrap to [-pi/2, pi/2): a parallel gripper is the same after a half turn."""
    return (angle + np.pi / 2) % np.pi - np.pi / 2


def horizontal_closing_yaw(R: np.ndarray, closing_axis: float) -> float:
    """Heading of the horizontal closing line nearest the object's closing axis (object-frame
    direction ``closing_axis`` in its xy plane) under rotation ``R``: the axis projected onto
    the table plane. Where it points nearly straight up (a tilt near 90 degrees about the
    perpendicular axis), the other footprint axis projected instead."""
    axis = R @ np.array([np.cos(closing_axis), np.sin(closing_axis), 0.0])
    if np.hypot(axis[0], axis[1]) < 0.3:
        axis = R @ np.array([-np.sin(closing_axis), np.cos(closing_axis), 0.0])
        return float(np.arctan2(axis[1], axis[0]) + np.pi / 2)
    return float(np.arctan2(axis[1], axis[0]))


def tool_pitch(q: np.ndarray) -> float:
    """Tool pitch above the horizontal (shoulder, elbow and wrist axes are parallel)."""
    return float(q[1] + q[2] + q[3])


@dataclass(frozen=True)
class HandGeometry:
    """The gripper seen from above with the tool pointing down, in metres: what a grasp
    planner needs to keep the hand off other objects. Along the closing line the palm reaches
    ``palm_half_length`` either side of the TCP and each finger ``finger_thickness`` beyond its
    pad face (the pads are ``opening`` apart); across the line the palm reaches
    ``palm_half_width`` and a finger ``finger_half_width``; the palm's underside is
    ``palm_above_tcp`` above the TCP; the pads open ``max_opening`` apart at most."""

    palm_half_length: float
    palm_half_width: float
    palm_above_tcp: float
    finger_thickness: float
    finger_half_width: float
    max_opening: float


class ArmKinematics:
    """Forward and inverse kinematics of the arm mounted at ``base_pos`` (world frame).

    The default mount is the scene's: the robot base on the table top at ``(0, 0, 0.75)``.
    """

    def __init__(self, base_pos: Sequence[float] | None = None) -> None:
        if base_pos is None:
            from scorbot_gym.sim.scene import TABLE_HEIGHT

            base_pos = (0.0, 0.0, TABLE_HEIGHT)
        root = mjcf.RootElement(model="scorbot_kinematics")
        root.compiler.angle = "radian"
        site = root.worldbody.add("site", name="robot_base", pos=list(base_pos))
        site.attach(build_arm())
        self.model = mujoco.MjModel.from_xml_string(root.to_xml_string(), root.get_assets())
        self.data = mujoco.MjData(self.model)
        m = self.model
        self.base_pos = np.asarray(base_pos, float)
        self._qpos = np.array([m.joint(ARM_PREFIX + j).qposadr[0] for j in ARM_JOINTS])
        self._dof = np.array([m.joint(ARM_PREFIX + j).dofadr[0] for j in ARM_JOINTS])
        self._tcp = m.site(ARM_PREFIX + "tcp").id
        self._jacp = np.zeros((3, m.nv))
        # Slices where the indices run in order (a fancy index costs IK ~4 us per iteration).
        self._qpos_at = _as_slice(self._qpos)
        self._dof4 = _as_slice(self._dof[:4])  # the joints IK moves (the wrist roll is kept)
        self._chain = self._planar_chain()
        self._base_xyz = tuple(self.base_pos.tolist())  # floats, once (IK runs every step)

    def _planar_chain(self) -> tuple[float, float, float, float, float]:
        """The arm's planar chain read from this model at zero joint angles, where every link
        points along the base's x axis: the shoulder axis's offset from the base axis and its
        height above the base, the upper arm, the forearm, and the TCP's distance from the wrist
        pitch axis (metres); what :meth:`ik_closed_form` needs."""
        m, d = self.model, self.data
        d.qpos[self._qpos] = 0.0
        mujoco.mj_kinematics(m, d)
        axes = [d.xanchor[m.joint(ARM_PREFIX + j).id].copy() for j in ARM_JOINTS[1:4]]
        shoulder, elbow, wrist = (a - self.base_pos for a in axes)
        tcp = d.site_xpos[self._tcp] - self.base_pos
        return (
            float(shoulder[0]),
            float(shoulder[2]),
            float(np.linalg.norm(elbow - shoulder)),
            float(np.linalg.norm(wrist - elbow)),
            float(np.linalg.norm(tcp - wrist)),
        )

    @functools.cached_property
    def hand(self) -> HandGeometry:
        """The hand's geometry, read from this model's palm and finger geoms (hand frame: x
        along the tool, y the closing direction, z across it; the fingers at their closed
        position, pad faces on the centre plane)."""
        m = self.model
        palm = m.geom(ARM_PREFIX + "palm")
        link = m.geom(ARM_PREFIX + "finger_left_link")
        tcp_x = m.site_pos[self._tcp][0]
        return HandGeometry(
            palm_half_length=float(palm.size[1]),
            palm_half_width=float(palm.size[2]),
            palm_above_tcp=float(tcp_x - (palm.pos[0] + palm.size[0])),
            finger_thickness=float(abs(link.pos[1]) + link.size[1]),
            finger_half_width=float(link.size[2]),
            max_opening=GRIPPER_MAX_OPENING,
        )

    def forward(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """TCP position and rotation matrix for joint angles ``q``."""
        d = self.data
        d.qpos[self._qpos] = q
        mujoco.mj_kinematics(self.model, d)
        return d.site_xpos[self._tcp].copy(), d.site_xmat[self._tcp].reshape(3, 3).copy()

    def closing_yaw(self, q: np.ndarray) -> float:
        """World heading of the fingers' closing direction (hand y axis) at ``q``."""
        _, R = self.forward(q)
        return float(np.arctan2(R[1, 1], R[0, 1]))

    def ik(
        self,
        target_pos: np.ndarray,
        pitch: float,
        q_init: np.ndarray,
        iterations: int = 60,
        damping: float = 0.02,
        tol: float = 1e-4,
    ) -> tuple[np.ndarray, float]:
        """Damped-least-squares IK for TCP position and tool pitch; wrist roll is kept.

        Returns the joint angles and the remaining position error (metres).
        """
        m, d = self.model, self.data
        q = np.minimum(np.maximum(np.array(q_init, dtype=float), JOINT_LOW), JOINT_HIGH)
        target = np.asarray(target_pos, dtype=float)
        # The textbook loop's arithmetic, operation for operation (the same joint angles to the
        # last bit), in buffers made once per call: an env with Cartesian actions runs this
        # every step, and numpy's per-call overheads were most of its cost.
        tcp, jacp = d.site_xpos[self._tcp], self._jacp  # views, refreshed by MuJoCo
        e = np.empty(4)
        e_pos, q_arm = e[:3], q[:4]
        J = np.empty((4, 4), order="F")  # the memory layout np.vstack gave it: same sums
        J[3] = (0.0, 1.0, 1.0, 1.0)  # tool pitch = q1 + q2 + q3
        J_pos = J[:3]
        reg = damping**2 * _EYE4
        err = np.inf
        for _ in range(iterations):
            d.qpos[self._qpos_at] = q
            mujoco.mj_kinematics(m, d)
            np.subtract(target, tcp, out=e_pos)
            e[3] = pitch - tool_pitch(q)
            err = math.sqrt(e_pos @ e_pos)  # np.linalg.norm's arithmetic
            if err < tol and abs(e[3]) < 1e-3:
                break
            mujoco.mj_comPos(m, d)  # what the Jacobian needs, once it is needed
            mujoco.mj_jacSite(m, d, jacp, None, self._tcp)
            J_pos[...] = jacp[:, self._dof4]
            dq = J.T @ _solve(J @ J.T + reg, e)
            biggest = max(map(abs, dq.tolist()))  # np.abs(dq).max(), for 4 numbers
            scale = min(1.0, 0.3 / (biggest + 1e-12))  # limit the step: stay on the branch
            q_arm += scale * dq  # then np.clip's arithmetic, in place:
            np.minimum(np.maximum(q_arm, _LOW4, out=q_arm), _HIGH4, out=q_arm)
        return q, err

    def ik_closed_form(
        self, target_pos: np.ndarray, pitch: float, q_init: np.ndarray, max_jump: float = 0.5
    ) -> np.ndarray | None:
        """The exact IK solution for TCP position and tool pitch on ``q_init``'s branch, or
        ``None`` where :meth:`ik` must decide; wrist roll is kept.

        The base turns about the vertical and the shoulder, elbow and wrist pitch axes are
        parallel, so the position and pitch fix the base angle and the wrist axis, and the
        shoulder and elbow follow from a two-link triangle: about 5 us where the damped least
        squares take about 40 (an env with Cartesian actions solves IK every step). The branch
        kept is ``q_init``'s: the elbow on its side, the base facing the target or, when that is
        nearer the current base angle, away from it (reaching over the back).

        ``None`` when the target is out of reach, a joint would pass its limit, or the solution
        moves some joint more than ``max_jump`` rad from ``q_init`` (a branch change near a
        singularity): there the damped least squares' compromise, which stays near ``q_init``,
        is the better answer. Where this solves, :meth:`ik` converges to the same joint angles
        within its tolerance (0.1 mm, 1 mrad).
        """
        q0, _, q2, _, q4 = (float(v) for v in q_init)
        offset, height, upper, fore, tool = self._chain
        bx, by, bz = self._base_xyz
        x, y, z = float(target_pos[0]) - bx, float(target_pos[1]) - by, float(target_pos[2]) - bz
        yaw, reach = math.atan2(y, x), math.hypot(x, y)
        behind = yaw - math.pi if yaw > 0.0 else yaw + math.pi
        if abs(behind - q0) < abs(yaw - q0):
            yaw, reach = behind, -reach
        # the wrist pitch axis, in the arm's plane, from the shoulder axis
        wx = reach - offset - tool * math.cos(pitch)
        wz = z - height - tool * math.sin(pitch)
        cos_elbow = (wx * wx + wz * wz - upper * upper - fore * fore) / (2.0 * upper * fore)
        if not -1.0 <= cos_elbow <= 1.0:
            return None  # out of reach
        elbow = math.acos(cos_elbow) if q2 > 0.0 else -math.acos(cos_elbow)
        shoulder = math.atan2(wz, wx) - math.atan2(
            fore * math.sin(elbow), upper + fore * math.cos(elbow)
        )
        q = (yaw, shoulder, elbow, pitch - shoulder - elbow)
        lo, hi = _LOW4_LIST, _HIGH4_LIST
        for i in range(4):
            if not lo[i] <= q[i] <= hi[i] or abs(q[i] - float(q_init[i])) > max_jump:
                return None
        return np.array((*q, min(max(q4, _ROLL_LOW), _ROLL_HIGH)))

    def roll_for_closing_yaw(self, q: np.ndarray, yaw: float, near: float | None = None) -> float:
        """Wrist roll that turns the closing direction to world heading ``yaw`` (tool down).

        A parallel gripper closes along the same line after a half turn, so every yaw has two
        rolls inside the joint's range. Without ``near`` the one in [-pi/2, pi/2) is returned;
        with it, the one nearest ``near`` (the current roll): a closing direction that crosses
        the half-turn boundary while the arm servos must not swing the wrist round by 180
        degrees over the object.
        """
        q0 = np.array(q, dtype=float)
        q0[4] = 0.0
        y0 = self.closing_yaw(q0)
        q0[4] = 0.5
        sign = np.sign(wrap_half_turn(self.closing_yaw(q0) - y0)) or 1.0
        roll = wrap_half_turn(sign * (yaw - y0))
        if near is None:
            return roll
        rolls = [
            r for r in (roll - np.pi, roll, roll + np.pi) if JOINT_LOW[4] <= r <= JOINT_HIGH[4]
        ]
        return float(min(rolls, key=lambda r: abs(r - near)))
