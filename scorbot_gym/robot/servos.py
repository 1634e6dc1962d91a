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
        self._geom_sets: dict[bytes, frozenset[int]] = {}
        # Per geom, the parts it belongs to, as bits: left finger 1, right finger 2, link 4.
        parts = np.zeros(m.ngeom, dtype=int)
        for bit, geoms in (
            (1, self.finger_geoms[0]),
            (2, self.finger_geoms[1]),
            (4, self.link_geoms),
        ):
            parts[geoms] |= bit
        self._parts = parts.tolist()

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
    def geom_set(self, geoms: np.ndarray) -> frozenset[int]:
        """``geoms`` as a set of ids, cached per set of ids (it is asked for every step)."""
        key = np.asarray(geoms, dtype=np.intp).tobytes()
        found = self._geom_sets.get(key)
        if found is None:
            found = self._geom_sets[key] = frozenset(np.asarray(geoms).ravel().tolist())
        return found

    def contacts_with(self, geoms: np.ndarray) -> tuple[bool, bool, bool]:
        """Whether the left finger, right finger and arm links touch any of ``geoms``.

        A plain loop over the contacts: there are a handful (2-12 in a grasp), and per-call
        overheads made array tests (``np.isin``: ~13 us a call) cost as much as the physics."""
        d = self.sim.data
        if not d.ncon:
            return False, False, False
        members, parts = self.geom_set(geoms), self._parts
        touching = 0  # bits of the parts touching one of ``geoms``
        for g1, g2 in d.contact.geom[: d.ncon].tolist():
            if g1 in members:
                touching |= parts[g2]
            elif g2 in members:
                touching |= parts[g1]
        return bool(touching & 1), bool(touching & 2), bool(touching & 4)
