"""The grasp-and-lift task: object placement, reward, success and failure causes."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from scorbot_gym.robot import Robot
from scorbot_gym.sim.simulation import ARM_PREFIX, Simulation, quat_to_mat

FAILURE_CAUSES = ("missed", "dropped", "collision", "timeout", "unstable")


@dataclass
class EpisodeState:
    rest_pos: np.ndarray
    held_time: float = 0.0
    ever_grasped: bool = False
    closed_empty: bool = False
    arm_collision: bool = False
    self_collision: bool = False
    success: bool = False


class GraspTask:
    """Lift the object at least ``lift_height`` above its resting place, between the fingers,
    for ``hold_time`` seconds of simulated time."""

    def __init__(
        self,
        sim: Simulation,
        robot: Robot,
        reward_type: str = "dense",
        lift_height: float = 0.05,
        hold_time: float = 0.5,
    ) -> None:
        if reward_type not in ("dense", "sparse"):
            raise ValueError(f"reward_type must be 'dense' or 'sparse', got {reward_type!r}")
        self.sim, self.robot = sim, robot
        self.reward_type = reward_type
        self.lift_height, self.hold_time = lift_height, hold_time
        self.state: EpisodeState | None = None
        m = sim.model
        self._table_geom = np.array([m.geom("table_top").id])
        # Contacts between two of these are the arm hitting itself (MuJoCo already skips
        # parent-child pairs and the arm excludes its neighbouring links).
        self._arm_geoms = np.array(
            [g for g in range(m.ngeom) if m.geom(g).name.startswith(ARM_PREFIX)]
        )
        self._arm_set = robot.geom_set(self._arm_geoms)
        # Where the fingers close, in the object frame (z = 0): fixed for the scene's object.
        self._grasp_offset = np.r_[sim.object_spec.model.grasp_point, 0.0]

    def place_object(self, rng: np.random.Generator, resting_index: int = 0) -> None:
        (x0, x1), (y0, y1) = self.sim.workspace_xy_bounds
        xy = rng.uniform([x0, y0], [x1, y1])
        yaw = rng.uniform(-np.pi, np.pi)
        pos, quat = self.sim.resting_pose(xy, yaw, resting_index)
        self.sim.set_object_pose(pos, quat)
        self.sim.forward()
        self.state = EpisodeState(rest_pos=pos)

    def grasp_point_world(self) -> np.ndarray:
        pos, quat = self.sim.object_pose()
        return pos + quat_to_mat(quat) @ self._grasp_offset

    def update(self, dt: float) -> dict:
        """Advance the episode bookkeeping after ``dt`` seconds; return the step's facts."""
        st = self.state
        obj_geoms = self.sim.object_geoms
        left, right, link_obj = self.robot.contacts_with(obj_geoms)
        _, _, link_table = self.robot.contacts_with(self._table_geom)
        grasped = left and right
        pos, _ = self.sim.object_pose()
        lift = float(pos[2] - st.rest_pos[2])
        lifted = lift >= self.lift_height
        st.held_time = st.held_time + dt if (grasped and lifted) else 0.0
        st.ever_grasped |= grasped
        st.arm_collision |= link_obj or link_table
        st.self_collision |= self.self_collision()
        opening = self.robot.gripper_opening
        st.closed_empty |= opening < 0.004 and not grasped
        st.success |= st.held_time >= self.hold_time - 1e-9
        fell = pos[2] < self.sim.table_height - 0.05
        gap = self.robot.tcp_pos - self.grasp_point_world()
        reach = math.sqrt(gap @ gap)  # np.linalg.norm's arithmetic, without its overhead
        return {
            "grasped": grasped,
            "touched": bool(left or right or link_obj),
            "lift": lift,
            "reach": reach,
            "fell": fell,
        }

    def self_collision(self) -> bool:
        """Whether two parts of the arm touch now (e.g. the hand folded onto the column)."""
        d, arm = self.sim.data, self._arm_set
        # a loop: a handful of contacts (see Robot.contacts_with)
        return any(g1 in arm and g2 in arm for g1, g2 in d.contact.geom[: d.ncon].tolist())

    def reward(self, facts: dict) -> float:
        if self.reward_type == "sparse":
            return float(self.state.success)
        lift_frac = np.clip(facts["lift"] / self.lift_height, 0.0, 1.0)
        return float(
            (1.0 - np.tanh(10.0 * facts["reach"]))
            + facts["grasped"] * (1.0 + 2.0 * lift_frac)
            + 10.0 * self.state.success
        )

    def failure_cause(self, facts: dict, unstable: bool) -> str:
        """Why an episode that ends now without success failed."""
        st = self.state
        if unstable:
            return "unstable"
        if facts["fell"] or (st.ever_grasped and not facts["grasped"]):
            return "dropped"
        if st.self_collision or (st.arm_collision and not st.ever_grasped):
            return "collision"
        if st.closed_empty and not st.ever_grasped:
            return "missed"
        return "timeout"
