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
        self._masks: dict[bytes, np.ndarray] = {}
        # Per geom, which parts it belongs to, as bits: left finger 1, right finger 2, link 4.
        self._part_bits = np.zeros(m.ngeom, dtype=np.uint8)
        for bit, geoms in (
            (1, self.finger_geoms[0]),
            (2, self.finger_geoms[1]),
            (4, self.link_geoms),
        ):
            self._part_bits[geoms] |= bit

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
        # np.clip's result, without its ~5 us of Python overhead (called every step)
        self.sim.data.ctrl[self.actuator_idx] = np.minimum(np.maximum(q, JOINT_LOW), JOINT_HIGH)

    def set_gripper_target(self, opening: float) -> None:
        self.sim.data.ctrl[self.gripper_actuator] = min(max(opening, 0.0), GRIPPER_MAX_OPENING)

    # --- contacts ------------------------------------------------------------------------
    def geom_mask(self, geoms: np.ndarray) -> np.ndarray:
        """A read-only ``bool (ngeom,)`` lookup: True at ``geoms``. Cached per set of ids, so a
        contact test is one gather per contact column (``np.isin`` cost ~13 us a call)."""
        ids = np.asarray(geoms, dtype=np.intp).ravel()
        key = ids.tobytes()
        mask = self._masks.get(key)
        if mask is None:
            mask = np.zeros(self.sim.model.ngeom, dtype=bool)
            mask[ids] = True
            mask.flags.writeable = False
            self._masks[key] = mask
        return mask

    def contacts_with(self, geoms: np.ndarray) -> tuple[bool, bool, bool]:
        """Whether the left finger, right finger and arm links touch any of ``geoms``."""
        d = self.sim.data
        if not d.ncon:
            return False, False, False
        pairs = d.contact.geom[: d.ncon]  # (ncon, 2): one array test instead of a Python loop
        g1, g2 = pairs[:, 0], pairs[:, 1]
        mask = self.geom_mask(geoms)
        in1, in2 = mask[g1], mask[g2]
        # the geom touching one of ``geoms`` (the second one when both are in ``geoms``)
        other = np.where(in1, g2, g1)[in1 | in2]
        bits = int(np.bitwise_or.reduce(self._part_bits[other])) if len(other) else 0
        return bool(bits & 1), bool(bits & 2), bool(bits & 4)
