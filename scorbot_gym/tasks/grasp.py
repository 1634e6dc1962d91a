"""The grasp-and-lift task: object placement, reward, success and failure causes."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from scorbot_gym.robot import Robot
from scorbot_gym.sim.simulation import ARM_PREFIX, Simulation, quat_to_mat

# "wrong_object" (a distractor lifted instead of the target) is decided by the ClutterTask.
FAILURE_CAUSES = ("missed", "dropped", "collision", "timeout", "unstable", "wrong_object")

#: The discount the dense reward is designed for (SB3's SAC/TQC/PPO default).
REWARD_GAMMA = 0.99
#: Largest shaping reward of one step: reaching (<= 1) + grasped (1) + lifted (<= 2).
SHAPING_MAX = 4.0
#: How much more than never finishing a success is worth (see :func:`grasp_reward`).
SUCCESS_MARGIN = 1.5
#: The one-off bonus on the step the task succeeds (the episode then terminates):
#: ``SUCCESS_MARGIN * SHAPING_MAX / (1 - REWARD_GAMMA)`` = 1.5 * 4 / 0.01 = 600.
SUCCESS_BONUS = SUCCESS_MARGIN * SHAPING_MAX / (1.0 - REWARD_GAMMA)
#: The reward terms, as ``info["reward_<term>"]`` (Gymnasium MuJoCo v5 style).
REWARD_TERMS = ("reach", "grasp", "lift", "success")
#: fingers closer than this (m) hold nothing: "closed empty" (the thinnest catalogue object is
#: several times wider); the scripted controller's re-grasp reads the same test
CLOSED_EMPTY_OPENING = 0.004


def grasp_reward(
    reach: float, grasped: bool, lift: float, success: bool, lift_height: float
) -> tuple[float, dict[str, float]]:
    """The dense reward of one step and its terms.

    Shaping: ``reach = 1 - tanh(10 * distance TCP-grasp point)`` (in [0, 1]), ``grasp = 1``
    while both fingers touch the object, ``lift = 2 * min(lift / lift_height, 1)`` while
    grasped: at most ``SHAPING_MAX = 4`` per step. Success (lifted ``lift_height`` for the
    task's hold time) pays ``SUCCESS_BONUS`` once and terminates the episode.

    Why the bonus is that large: with bootstrapping at the time limit (SB3 treats truncation
    as non-terminal), never finishing while holding the object just under ``lift_height`` is
    worth up to ``SHAPING_MAX / (1 - gamma)`` = 4 / 0.01 = 400 at ``gamma = REWARD_GAMMA``.
    A success on step ``T`` is worth ``sum_{t<T} gamma^t r_t + gamma^T * SUCCESS_BONUS``;
    since ``SUCCESS_BONUS > SHAPING_MAX / (1 - gamma)``, it beats every continuation that
    does not finish from the same step on (those collect at most ``gamma^T * 400``): success
    on step T is worth more than anything the same prefix can be followed by. (The previous
    bonus, 10, made holding worth ~400 against ~60 for succeeding.)
    """
    lift_frac = float(np.clip(lift / lift_height, 0.0, 1.0))
    terms = {
        "reach": float(1.0 - np.tanh(10.0 * reach)),
        "grasp": float(grasped),
        "lift": 2.0 * lift_frac * float(grasped),
        "success": SUCCESS_BONUS * float(success),
    }
    return float(sum(terms.values())), terms


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
        st.closed_empty |= opening < CLOSED_EMPTY_OPENING and not grasped
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

    def reward(self, facts: dict) -> tuple[float, dict[str, float]]:
        """The step's reward and its terms (see :func:`grasp_reward`); the sparse reward is
        1 on success, its only term."""
        if self.reward_type == "sparse":
            return float(self.state.success), {"success": float(self.state.success)}
        return grasp_reward(
            facts["reach"], facts["grasped"], facts["lift"], self.state.success, self.lift_height
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
