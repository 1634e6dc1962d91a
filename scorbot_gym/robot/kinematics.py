"""Kinematics of the SCORBOT arm on its own model: FK, IK and the gripper's closing direction.

Policies need the arm's kinematics to turn a target pose into joint angles, but must not reach
into a running environment (in a subprocess vector env there is none to reach). So this model
compiles the arm's MJCF alone, mounted where the scene mounts it, and keeps its own MuJoCo data:
it is the public, documented kinematic description of the robot, the same chain the simulator
uses, and it is cheap to build (a few milliseconds).
"""

from __future__ import annotations

from collections.abc import Sequence

import mujoco
import numpy as np

from scorbot_gym import _gl
from scorbot_gym.sim.arm import ARM_JOINTS, JOINT_RANGES_DEG, build_arm

mjcf = _gl.import_mjcf()  # dm_control with its own renderer off (see _gl)

JOINT_LOW = np.deg2rad([JOINT_RANGES_DEG[j][0] for j in ARM_JOINTS])
JOINT_HIGH = np.deg2rad([JOINT_RANGES_DEG[j][1] for j in ARM_JOINTS])
ARM_PREFIX = "scorbot/"


def wrap_half_turn(angle: float) -> float:
    """Wrap to [-pi/2, pi/2): a parallel gripper is the same after a half turn."""
    return (angle + np.pi / 2) % np.pi - np.pi / 2


def tool_pitch(q: np.ndarray) -> float:
    """Tool pitch above the horizontal (shoulder, elbow and wrist axes are parallel)."""
    return float(q[1] + q[2] + q[3])


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
        q = np.clip(np.array(q_init, dtype=float), JOINT_LOW, JOINT_HIGH)
        err = np.inf
        for _ in range(iterations):
            d.qpos[self._qpos] = q
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            e = np.r_[target_pos - d.site_xpos[self._tcp], pitch - tool_pitch(q)]
            err = float(np.linalg.norm(e[:3]))
            if err < tol and abs(e[3]) < 1e-3:
                break
            mujoco.mj_jacSite(m, d, self._jacp, None, self._tcp)
            J = np.vstack([self._jacp[:, self._dof[:4]], [0.0, 1.0, 1.0, 1.0]])
            dq = J.T @ np.linalg.solve(J @ J.T + damping**2 * np.eye(4), e)
            scale = min(1.0, 0.3 / (np.abs(dq).max() + 1e-12))  # limit the step: stay on branch
            q[:4] = np.clip(q[:4] + scale * dq, JOINT_LOW[:4], JOINT_HIGH[:4])
        return q, err

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
