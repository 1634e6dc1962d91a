"""The SCORBOT arm in a :class:`Simulation`: joint servos, gripper, TCP, inverse kinematics."""

from __future__ import annotations

import mujoco
import numpy as np

from scorbot_gym.sim.arm import ARM_JOINTS, GRIPPER_MAX_OPENING, JOINT_RANGES_DEG
from scorbot_gym.sim.simulation import ARM_PREFIX, Simulation

JOINT_LOW = np.deg2rad([JOINT_RANGES_DEG[j][0] for j in ARM_JOINTS])
JOINT_HIGH = np.deg2rad([JOINT_RANGES_DEG[j][1] for j in ARM_JOINTS])


def wrap_half_turn(angle: float) -> float:
    """Wrap to [-pi/2, pi/2): a parallel gripper is the same after a half turn."""
    return (angle + np.pi / 2) % np.pi - np.pi / 2


class Robot:
    """Reads and commands the arm; solves IK on a private copy of the state."""

    def __init__(self, sim: Simulation) -> None:
        self.sim = sim
        m = sim.model
        self.qpos_idx = sim.arm_qpos
        self.dof_idx = np.array([m.joint(ARM_PREFIX + j).dofadr[0] for j in ARM_JOINTS])
        self.actuator_idx = np.array([m.actuator(ARM_PREFIX + j).id for j in ARM_JOINTS])
        self.gripper_actuator = m.actuator(ARM_PREFIX + "gripper").id
        self.finger_qpos = np.array(
            [m.joint(ARM_PREFIX + f"finger_{s}").qposadr[0] for s in ("left", "right")]
        )
        self.tcp_site = m.site(ARM_PREFIX + "tcp").id
        self.hand_body = m.body(ARM_PREFIX + "hand").id
        finger_bodies = [m.body(ARM_PREFIX + f"finger_{s}").id for s in ("left", "right")]
        self.finger_geoms = [np.flatnonzero(m.geom_bodyid == b) for b in finger_bodies]
        arm_bodies = [m.body(ARM_PREFIX + b).id for b in ("upper_arm", "forearm", "wrist", "hand")]
        self.link_geoms = np.flatnonzero(np.isin(m.geom_bodyid, arm_bodies))
        self._ik_data = mujoco.MjData(m)
        self._ik_data.qpos[:] = m.qpos0
        self._jacp = np.zeros((3, m.nv))

    # --- state ---------------------------------------------------------------------------
    @property
    def joint_pos(self) -> np.ndarray:
        return self.sim.data.qpos[self.qpos_idx].copy()

    @property
    def joint_vel(self) -> np.ndarray:
        return self.sim.data.qvel[self.dof_idx].copy()

    @property
    def gripper_opening(self) -> float:
        return float(self.sim.data.qpos[self.finger_qpos].sum())

    @property
    def tcp_pos(self) -> np.ndarray:
        return self.sim.data.site_xpos[self.tcp_site].copy()

    @property
    def tcp_quat(self) -> np.ndarray:
        q = np.empty(4)
        mujoco.mju_mat2Quat(q, self.sim.data.site_xmat[self.tcp_site])
        return q

    @staticmethod
    def tool_pitch(q: np.ndarray) -> float:
        """Tool pitch above the horizontal (shoulder, elbow and wrist axes are parallel)."""
        return float(q[1] + q[2] + q[3])

    # --- commands ------------------------------------------------------------------------
    def set_joint_targets(self, q: np.ndarray) -> None:
        self.sim.data.ctrl[self.actuator_idx] = np.clip(q, JOINT_LOW, JOINT_HIGH)

    def set_gripper_target(self, opening: float) -> None:
        self.sim.data.ctrl[self.gripper_actuator] = np.clip(opening, 0.0, GRIPPER_MAX_OPENING)

    # --- contacts ------------------------------------------------------------------------
    def contacts_with(self, geoms: np.ndarray) -> tuple[bool, bool, bool]:
        """Whether the left finger, right finger and arm links touch any of ``geoms``."""
        d = self.sim.data
        pairs = d.contact.geom[: d.ncon]
        left = right = link = False
        for g1, g2 in pairs:
            other = g2 if g1 in geoms else (g1 if g2 in geoms else -1)
            if other < 0:
                continue
            left |= other in self.finger_geoms[0]
            right |= other in self.finger_geoms[1]
            link |= other in self.link_geoms
        return left, right, link

    # --- kinematics ----------------------------------------------------------------------
    def forward_kinematics(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """TCP position and rotation matrix for joint angles ``q`` (no effect on the simulation)."""
        d = self._ik_data
        d.qpos[self.qpos_idx] = q
        mujoco.mj_kinematics(self.sim.model, d)
        return d.site_xpos[self.tcp_site].copy(), d.site_xmat[self.tcp_site].reshape(3, 3).copy()

    def closing_yaw(self, q: np.ndarray) -> float:
        """World heading of the fingers' closing direction (hand y axis) at ``q``."""
        _, R = self.forward_kinematics(q)
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
        m, d = self.sim.model, self._ik_data
        q = np.clip(np.array(q_init, dtype=float), JOINT_LOW, JOINT_HIGH)
        err = np.inf
        for _ in range(iterations):
            d.qpos[self.qpos_idx] = q
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            e = np.r_[target_pos - d.site_xpos[self.tcp_site], pitch - self.tool_pitch(q)]
            err = float(np.linalg.norm(e[:3]))
            if err < tol and abs(e[3]) < 1e-3:
                break
            mujoco.mj_jacSite(m, d, self._jacp, None, self.tcp_site)
            J = np.vstack([self._jacp[:, self.dof_idx[:4]], [0.0, 1.0, 1.0, 1.0]])
            dq = J.T @ np.linalg.solve(J @ J.T + damping**2 * np.eye(4), e)
            scale = min(1.0, 0.3 / (np.abs(dq).max() + 1e-12))  # limit the step: stay on branch
            q[:4] = np.clip(q[:4] + scale * dq, JOINT_LOW[:4], JOINT_HIGH[:4])
        return q, err

    def roll_for_closing_yaw(self, q: np.ndarray, yaw: float) -> float:
        """Wrist roll that turns the closing direction to world heading ``yaw`` (tool down)."""
        q0 = np.array(q, dtype=float)
        q0[4] = 0.0
        y0 = self.closing_yaw(q0)
        q0[4] = 0.5
        sign = np.sign(wrap_half_turn(self.closing_yaw(q0) - y0)) or 1.0
        return wrap_half_turn(sign * (yaw - y0))
