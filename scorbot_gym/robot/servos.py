"""The SCORBOT arm in a :class:`Simulation`: joint servos, gripper, TCP, contacts.

Kinematics (FK/IK) live in :mod:`scorbot_gym.robot.kinematics`, on the arm's own model, so that
policies can use them without a simulation.
"""

from __future__ import annotations

import mujoco
import numpy as np

from scorbot_gym.robot.kinematics import JOINT_HIGH, JOINT_LOW, ArmKinematics
from scorbot_gym.sim.arm import ARM_JOINTS, GRIPPER_MAX_OPENING
from scorbot_gym.sim.simulation import ARM_PREFIX, Simulation


class Robot:
    """Reads and commands the arm in a simulation; ``kinematics`` is its FK/IK model (pass one
    to share it between the scenes of an env: it is the same arm in every scene)."""

    def __init__(self, sim: Simulation, kinematics: ArmKinematics | None = None) -> None:
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
        self.kinematics = kinematics or ArmKinematics()

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

    # --- commands ------------------------------------------------------------------------
    def set_joint_targets(self, q: np.ndarray) -> None:
        self.sim.data.ctrl[self.actuator_idx] = np.clip(q, JOINT_LOW, JOINT_HIGH)

    def set_gripper_target(self, opening: float) -> None:
        self.sim.data.ctrl[self.gripper_actuator] = np.clip(opening, 0.0, GRIPPER_MAX_OPENING)

    # --- contacts ------------------------------------------------------------------------
    def contacts_with(self, geoms: np.ndarray) -> tuple[bool, bool, bool]:
        """Whether the left finger, right finger and arm links touch any of ``geoms``."""
        d = self.sim.data
        pairs = d.contact.geom[: d.ncon]  # (ncon, 2): one array test instead of a Python loop
        if not len(pairs):
            return False, False, False
        g1, g2 = pairs[:, 0], pairs[:, 1]
        in1, in2 = np.isin(g1, geoms), np.isin(g2, geoms)
        other = np.where(in1, g2, np.where(in2, g1, -1))  # the geom touching one of ``geoms``
        other = other[other >= 0]
        return (
            bool(np.isin(other, self.finger_geoms[0]).any()),
            bool(np.isin(other, self.finger_geoms[1]).any()),
            bool(np.isin(other, self.link_geoms).any()),
        )
