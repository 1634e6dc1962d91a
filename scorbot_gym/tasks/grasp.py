"""The grasp-and-lift task: object placement, reward, success and failure causes."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from scorbot_gym.robot import Robot
from scorbot_gym.robot.kinematics import horizontal_closing_yaw, tool_pitch
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
#: The reward types: ``dense`` (:func:`grasp_reward`, what every shipped policy and result was
#: trained with), ``normalized_dense`` (:func:`normalized_grasp_reward`, for learning from
#: scratch), ``normalized_pregrasp`` (the same with a pre-grasp stage, :func:`pregrasp_progress`)
#: and ``sparse`` (1 on success).
REWARD_TYPES = ("dense", "normalized_dense", "normalized_pregrasp", "sparse")
#: The terms of ``reward_type="normalized_dense"``; they sum to the reward.
NORMALIZED_REWARD_TERMS = ("reach", "grasp", "lift", "hold", "collision", "success")
#: The terms of ``reward_type="normalized_pregrasp"``; they sum to the reward.
PREGRASP_REWARD_TERMS = ("reach", "pregrasp", "grasp", "lift", "hold", "collision", "success")
#: The pre-grasp stage's open hand: pads this far apart (m) count as fully open (the fingers
#: open 0.075 at most; every catalogue grasp is narrower than 0.06).
PREGRASP_OPENING = 0.06
#: Within this distance (m) of the grasp point the hand may close at no cost to the stage.
PREGRASP_RADIUS = 0.02
#: ``k`` of the normalised reach term ``1 - tanh(k d)``, 1/m: ManiSkill's PickCube uses 5 for
#: start distances of ~0.15 m; ours are twice that (median 0.34 m), where 5 leaves 6 % of the
#: term and 3 leaves 23 %, with a slope that still rises 2.5-fold towards the grasp point.
NORMALIZED_REACH_K = 3.0
#: The most a step that does not succeed can pay: ``(1 - REWARD_GAMMA) / 2`` = 0.005, so that
#: never finishing is worth at most half of a success (see :func:`normalized_grasp_reward`).
NORMALIZED_SHAPING_MAX = (1.0 - REWARD_GAMMA) / 2.0


def normalized_shaping_max(reward_gamma: float = REWARD_GAMMA) -> float:
    """``w``, the most a step that does not succeed pays in the normalised rewards built for
    a learner's discount ``reward_gamma``: ``(1 - reward_gamma) / 2``, the largest ``w`` that
    keeps never finishing worth at most half of a success for every discount up to
    ``reward_gamma`` (see :func:`normalized_grasp_reward`)."""
    if not 0.0 < reward_gamma < 1.0:
        raise ValueError(f"reward_gamma must be a discount in (0, 1), got {reward_gamma!r}")
    return (1.0 - reward_gamma) / 2.0


def reward_gamma_for(reward_type: str, reward_gamma: object) -> float:
    """``reward_gamma`` checked for ``reward_type``: a discount in (0, 1), and only the
    normalised rewards are built for a discount of one's choosing (``dense`` is built for
    ``REWARD_GAMMA``, ``sparse`` for none), so anything else with them is refused."""
    try:
        value = float(reward_gamma) if not isinstance(reward_gamma, bool) else math.nan
    except (TypeError, ValueError):
        value = math.nan
    if not 0.0 < value < 1.0:
        raise ValueError(f"reward_gamma must be a discount in (0, 1), got {reward_gamma!r}")
    if value != REWARD_GAMMA and not reward_type.startswith("normalized"):
        raise ValueError(
            f"reward_gamma applies to the normalised rewards (normalized_dense, "
            f"normalized_pregrasp); reward_type {reward_type!r} is built for {REWARD_GAMMA}"
        )
    return value


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


def pregrasp_progress(
    reach: float, heading_error: float, tilt: float, opening: float, grasped: bool
) -> float:
    """How far the hand is in the pre-grasp pose, in [0, 1]: the mean of three parts, each
    falling linearly to 0 at a quarter turn: the closing line turned to the object's
    (``heading_error`` wrapped to a half turn: the fingers are the same after one), the tool
    pointing straight down (``tilt`` from vertical), and the hand open (pads
    ``PREGRASP_OPENING`` apart; counted as open within ``PREGRASP_RADIUS`` of the grasp point,
    where it is to close). 1 while grasped.

    Why: with reach, grasp, lift and hold alone, a learner from scratch finds a hover above
    the object and stays there: lower, a closed, turned or tilted hand pushes the object away
    or touches it with the palm, and nothing pays for the pose that makes the last centimetres
    possible (measured in ``benchmarks/notes/2026-11-27-rl-from-scratch.md``). This is the
    scripted controller's own pre-grasp (the grasp frame is upright: a vertical approach,
    turned to the closing line, open until the point), in the reward, not in the policy;
    Meta-World's pick rewards pay for the fingers caging the object for the same reason.
    Moving closer never lowers it, and closing at the grasp point costs nothing.
    """
    if grasped:
        return 1.0
    quarter = math.pi / 2
    heading = 1.0 - abs((heading_error + quarter) % math.pi - quarter) / quarter
    vertical = 1.0 - min(abs(tilt) / quarter, 1.0)
    near = 1.0 - min(reach / PREGRASP_RADIUS, 1.0)
    open_hand = max(min(opening / PREGRASP_OPENING, 1.0), near)
    return (heading + vertical + open_hand) / 3.0


def closing_progress(reach: float, opening: float, grasped: bool) -> float:
    """The grasp stage of ``normalized_pregrasp``, in [0, 1]: 1 while both fingers hold the
    object; before that, up to half for closing the hand near the grasp point (how closed,
    times how near within ``PREGRASP_RADIUS``), so that a hand at the point is paid for
    starting to close before the fingers touch. Never as much as a grasp.

    Why: the fingers touch only after the hand has closed part of the way, so without it
    the one sequence that pays (reach, close, lift, hold) starts with steps that pay nothing
    (the notes above). Meta-World's pick rewards pay for closing the gripper near the object
    for the same reason.
    """
    if grasped:
        return 1.0
    near = 1.0 - min(reach / PREGRASP_RADIUS, 1.0)
    closed = 1.0 - min(opening / PREGRASP_OPENING, 1.0)
    return 0.5 * near * closed


def normalized_grasp_reward(
    reach: float,
    grasped: bool,
    lift: float,
    held_time: float,
    collision: bool,
    success: bool,
    lift_height: float,
    hold_time: float,
    pregrasp: float | None = None,
    closing: float | None = None,
    shaping_max: float = NORMALIZED_SHAPING_MAX,
) -> tuple[float, dict[str, float]]:
    """The normalised dense reward of one step (in [0, 1]) and its terms (they sum to it).

    Four stages, each a progress in [0, 1] as in ManiSkill's PickCube: ``reach = 1 - tanh(3 d)``
    (``d`` the TCP's distance to the grasp point), ``grasp = 1`` while both fingers touch the
    object, ``lift = min(lift / lift_height, 1)`` while grasped, ``hold = held_time /
    hold_time`` (time held at the lift height, towards success). A step that does not succeed
    pays their mean times ``w = NORMALIZED_SHAPING_MAX = (1 - gamma) / 2`` = 0.005; the step
    that succeeds (and terminates the episode) pays ``1 - w`` more, so every reward is in
    [0, 1] and the success step's is at least ``1 - w`` = 0.995.

    Why success is worth more than any way of not finishing, at ``gamma = REWARD_GAMMA`` =
    0.99 with the 150-step time limit bootstrapped (SB3 treats truncation as non-terminal, so
    the critic values a continuation as if it never ended): a continuation that never succeeds
    collects at most ``w / (1 - gamma)`` = 0.5, whatever it does (the time limit only lowers
    this to ``w (1 - gamma^n) / (1 - gamma)`` for n steps left); one that succeeds ``n`` steps
    later collects at least ``gamma^n (1 - w)``, which is more for every ``n <= 68``
    (``0.99^68 * 0.995 = 0.50``): finishing within 68 steps beats never finishing from any
    state, and finishing now beats it by at least 0.495. The reward depends on ``gamma`` only
    through ``w``: for any discount below 0.995 the bound still holds; a learner with a larger
    discount should use another reward. A learner with a smaller one sees a shorter reach of
    the success: at ``gamma = 0.8`` (ManiSkill3's SAC baseline) never finishing is worth at
    most ``w / 0.2`` = 0.025 and a success within 16 steps more (``0.8^16 * 0.995 = 0.028``).
    Rewards stay >= 0, so ending an episode any other way
    (the object knocked off the table) is worth 0 from then on: never better than going on.

    Why ``w`` is small: the bound above needs ``w <= (1 - gamma) / 2`` with a success worth 1.
    The old ``dense`` reward (4 per step, +600 once) paid 0.002 per step at the median start
    distance, 1/270,000 of a success; here the reach term there is 23 % of its maximum
    (``1 - tanh(3 * 0.34)``), ``0.23 * w / 4`` = 2.9e-4 per step, 1/3,500 of a success. A
    learner may see the reward scaled (the ``reward_scale`` hyperparameter: SAC's scratch
    entries use 200, steps of <= 1, as SAC's defaults expect); scaling keeps every ordering.

    Collisions: a step on which an arm link (not a finger) touches the table, pushes the
    object before both fingers hold it, or the arm hits itself pays nothing (the ``collision``
    term is minus the step's shaping), so a collision costs what the step would have earned,
    and a path that reaches the object through the table earns less than one around it. Not a
    termination: the episode's success and failure semantics are the env's, the same for
    every reward type, and an early exploration that brushes the table should not end it.

    ``pregrasp`` (``reward_type="normalized_pregrasp"``, :func:`pregrasp_progress`): a fifth
    stage after reach; the five progresses' mean times ``w``, so every bound above holds.
    ``closing`` (the same reward type, :func:`closing_progress`): the grasp stage's progress
    in place of ``grasped`` alone, still in [0, 1]. With the pre-grasp stage a collision costs
    the approach's pay (reach and pre-grasp), not the step's: a step's whole pay against the
    little the last centimetres earn keeps a learner away from the object (the notes above);
    the anchors' dense rewards (ManiSkill PickCube, robosuite Lift, Meta-World) charge nothing.
    """
    progress = {"reach": 1.0 - math.tanh(NORMALIZED_REACH_K * reach)}
    if pregrasp is not None:
        progress["pregrasp"] = pregrasp
    progress["grasp"] = float(grasped) if closing is None else closing
    progress["lift"] = min(max(lift / lift_height, 0.0), 1.0) * float(grasped)
    progress["hold"] = min(max(held_time / hold_time, 0.0), 1.0)
    stage_weight = shaping_max / len(progress)
    terms = {k: stage_weight * v for k, v in progress.items()}
    # a collision costs the whole step's shaping; with the pre-grasp stage, the approach's only
    lost = ("reach", "pregrasp") if pregrasp is not None else tuple(terms)
    terms["collision"] = -sum(terms[k] for k in lost) if collision else 0.0
    terms["success"] = (1.0 - shaping_max) if success else 0.0
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
        reward_gamma: float = REWARD_GAMMA,
    ) -> None:
        if reward_type not in REWARD_TYPES:
            raise ValueError(f"reward_type must be one of {REWARD_TYPES}, got {reward_type!r}")
        self.sim, self.robot = sim, robot
        self.reward_type = reward_type
        #: ``w`` of the normalised rewards (unused by ``dense`` and ``sparse``)
        self.shaping_max = normalized_shaping_max(reward_gamma)
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
        self._grasp_yaw = float(sim.object_spec.model.grasp_yaw)

    def place_object(self, rng: np.random.Generator, resting_index: int = 0) -> None:
        (x0, x1), (y0, y1) = self.sim.workspace_xy_bounds
        xy = rng.uniform([x0, y0], [x1, y1])
        yaw = rng.uniform(-np.pi, np.pi)
        pos, quat = self.sim.resting_pose(xy, yaw, resting_index)
        self.sim.set_object_pose(pos, quat)
        self.sim.forward()
        self.state = EpisodeState(rest_pos=pos)

    def heading_error(self) -> float:
        """The hand's closing line minus the object's (the scripted controller's), radians."""
        _, quat = self.sim.object_pose()
        closing = horizontal_closing_yaw(quat_to_mat(quat), self._grasp_yaw)
        return self.robot.kinematics.closing_yaw(self.robot.joint_pos) - closing

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
        self_collision = self.self_collision()
        st.arm_collision |= link_obj or link_table
        st.self_collision |= self_collision
        opening = self.robot.gripper_opening
        st.closed_empty |= opening < CLOSED_EMPTY_OPENING and not grasped
        st.success |= st.held_time >= self.hold_time - 1e-9
        fell = pos[2] < self.sim.table_height - 0.05
        gap = self.robot.tcp_pos - self.grasp_point_world()
        reach = math.sqrt(gap @ gap)  # np.linalg.norm's arithmetic, without its overhead
        if self.reward_type == "normalized_pregrasp":
            tilt = tool_pitch(self.robot.joint_pos) + math.pi / 2  # 0: pointing straight down
            pregrasp = pregrasp_progress(reach, self.heading_error(), tilt, opening, grasped)
            closing = closing_progress(reach, opening, grasped)
        else:
            pregrasp = closing = None
        return {
            "pregrasp": pregrasp,
            "closing": closing,
            "grasped": grasped,
            "touched": bool(left or right or link_obj),
            "lift": lift,
            "reach": reach,
            "fell": fell,
            # an arm link on the table, pushing the object it does not hold, or on itself
            "collision": bool(link_table or self_collision or (link_obj and not grasped)),
        }

    def self_collision(self) -> bool:
        """Whether two parts of the arm touch now (e.g. the hand folded onto the column)."""
        d, arm = self.sim.data, self._arm_set
        # a loop: a handful of contacts (see Robot.contacts_with)
        return any(g1 in arm and g2 in arm for g1, g2 in d.contact.geom[: d.ncon].tolist())

    @property
    def reward_terms(self) -> tuple[str, ...]:
        """The terms of this reward type, each in ``info["reward_<term>"]``."""
        if self.reward_type == "normalized_pregrasp":
            return PREGRASP_REWARD_TERMS
        return NORMALIZED_REWARD_TERMS if self.reward_type == "normalized_dense" else REWARD_TERMS

    def reward(self, facts: dict) -> tuple[float, dict[str, float]]:
        """The step's reward and its terms (see :func:`grasp_reward` and
        :func:`normalized_grasp_reward`); the sparse reward is 1 on success, its only term."""
        st = self.state
        if self.reward_type == "sparse":
            return float(st.success), {"success": float(st.success)}
        if self.reward_type in ("normalized_dense", "normalized_pregrasp"):
            return normalized_grasp_reward(
                facts["reach"],
                facts["grasped"],
                facts["lift"],
                st.held_time,
                facts["collision"],
                st.success,
                self.lift_height,
                self.hold_time,
                facts["pregrasp"],
                facts["closing"],
                self.shaping_max,
            )
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
