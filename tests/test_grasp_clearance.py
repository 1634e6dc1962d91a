"""The scripted grasp among neighbours (issue 37): the equivalent closing line or off-centre
grasp chosen to keep the open hand off the other objects, the pre-grasp aperture, and the
neighbours in the observation (from the ground truth for the oracle)."""

from __future__ import annotations

import numpy as np
import pytest

from scorbot_gym.envs.factory import make_env
from scorbot_gym.evaluation.episodes import run_episode
from scorbot_gym.objects import get_object
from scorbot_gym.perception.neighbours import (
    MAX_NEIGHBOUR_POINTS,
    footprint_points,
    pack_points,
)
from scorbot_gym.perception.registry import FunctionPoseSource
from scorbot_gym.policies import ScriptedGraspPolicy
from scorbot_gym.policies.grasp_clearance import (
    APERTURE_MARGIN,
    COMFORTABLE_CLEARANCE,
    choose_grasp,
    grasp_candidates,
    hand_clearance,
    horizontal_closing_yaw,
)
from scorbot_gym.robot import ArmKinematics
from scorbot_gym.sim.scene import TABLE_HEIGHT
from scorbot_gym.sim.simulation import quat_to_mat
from scorbot_gym.wrappers.pose_observation import PoseEstimateObservation

HAND = ArmKinematics().hand


def _disc(centre_xy, radius: float, height: float) -> np.ndarray:
    """A round neighbour standing at ``centre_xy``: its footprint's points."""
    t = np.linspace(0, 2 * np.pi, 40, endpoint=False)
    verts = np.c_[centre_xy[0] + radius * np.cos(t), centre_xy[1] + radius * np.sin(t)]
    verts = np.vstack([np.c_[verts, np.full(40, TABLE_HEIGHT)], np.c_[verts, np.full(40, height)]])
    return footprint_points(verts, TABLE_HEIGHT)


def _resting(name: str, yaw: float = 0.0):
    spec = get_object(name)
    R_yaw = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
    R = R_yaw @ quat_to_mat(spec.resting_quats[0])
    pos = np.array([0.3, 0.0, TABLE_HEIGHT - (spec.mesh_vertices() @ R.T)[:, 2].min()])
    grasp = pos + R @ np.r_[spec.model.grasp_point, 0.0]
    return spec, R, pos, grasp, horizontal_closing_yaw(R, spec.model.grasp_yaw)


def test_a_symmetric_object_turns_its_closing_line_away_from_a_neighbour():
    spec, R, pos, grasp, yaw = _resting("tomato_soup_can", yaw=0.4)
    free = grasp_candidates(spec, R, pos, grasp, yaw, np.zeros((0, 3)), HAND)
    assert len(free) > 1  # an upright can: every line is a grasp
    assert choose_grasp(free) is free[0] and free[0].yaw == yaw  # nothing near: the plan as before
    # a neighbour standing where the nominal line's finger comes down
    along = np.array([np.cos(yaw), np.sin(yaw)])
    blocked = _disc(grasp[:2] + 0.07 * along, 0.02, TABLE_HEIGHT + 0.1)
    cands = grasp_candidates(spec, R, pos, grasp, yaw, blocked, HAND)
    assert cands[0].clearance < 0
    chosen = choose_grasp(cands)
    assert chosen.clearance >= COMFORTABLE_CLEARANCE
    assert abs(np.sin(chosen.yaw - yaw)) > 0.5  # turned well away from the neighbour
    assert np.allclose(chosen.offset, 0.0, atol=1e-3)  # the grasp point stays on the axis


def test_a_single_line_object_slides_along_itself_away_from_a_neighbour():
    spec, R, pos, grasp, yaw = _resting("large_marker")
    along = np.array([np.cos(yaw), np.sin(yaw)])
    across = np.array([-along[1], along[0]])
    # a neighbour next to one finger at the centre, on one side of the marker's middle
    blocked = _disc(grasp[:2] + 0.045 * along + 0.012 * across, 0.015, TABLE_HEIGHT + 0.05)
    cands = grasp_candidates(spec, R, pos, grasp, yaw, blocked, HAND)
    assert len({round(c.yaw, 6) for c in cands}) == 1  # one closing line only
    chosen = choose_grasp(cands)
    assert cands[0].clearance < chosen.clearance and chosen.clearance > 0.005
    assert chosen.slide < 0  # away from the neighbour's side
    assert abs(chosen.slide) <= 0.25 * 2 * spec.model.half_extents.max() + 1e-9


def test_the_fingers_open_to_the_object_plus_a_margin():
    for name in ("large_marker", "box", "lego_duplo"):  # the box mesh has 8 vertices
        spec, R, pos, grasp, yaw = _resting(name, yaw=1.0)
        nominal = grasp_candidates(spec, R, pos, grasp, yaw, np.zeros((0, 3)), HAND)[0]
        expected = spec.model.grasp_width + 2 * APERTURE_MARGIN
        assert nominal.aperture == pytest.approx(min(expected, HAND.max_opening), abs=0.002)
    spec, R, pos, grasp, yaw = _resting("tomato_soup_can")
    full = grasp_candidates(spec, R, pos, grasp, yaw, np.zeros((0, 3)), HAND, margin=None)
    assert full[0].aperture == HAND.max_opening  # margin=None: the old fully open hand


def test_the_palm_counts_only_neighbours_taller_than_its_underside():
    grasp = np.array([0.3, 0.0, TABLE_HEIGHT + 0.02])
    under_palm = np.array([[0.34, 0.0, 0.0]])  # on the closing line (yaw 0) past a finger
    low = hand_clearance(under_palm + [0, 0, TABLE_HEIGHT + 0.03], grasp, 0.0, 0.04, HAND)
    tall = hand_clearance(under_palm + [0, 0, TABLE_HEIGHT + 0.12], grasp, 0.0, 0.04, HAND)
    assert low > 0 > tall
    assert hand_clearance(np.zeros((0, 3)), grasp, 0.0, 0.04, HAND) == np.inf


def test_points_are_packed_into_the_fixed_rows():
    pts = np.random.default_rng(0).uniform(0, 0.3, (3 * MAX_NEIGHBOUR_POINTS, 3))
    rows, valid = pack_points(pts)
    assert rows.shape == (MAX_NEIGHBOUR_POINTS, 3) and 0 < valid.sum() <= MAX_NEIGHBOUR_POINTS
    assert np.all(rows[valid == 0] == 0)
    few, valid_few = pack_points(pts[:5])
    assert valid_few.sum() == 5 and np.array_equal(few[:5], pts[:5])


@pytest.fixture(scope="module")
def oracle_clutter_env():
    env = make_env("ScorbotGrasp-v0", pose="oracle", distractors=2)
    yield env
    env.close()


def test_the_oracle_reports_the_other_objects_in_the_observation(oracle_clutter_env):
    env = oracle_clutter_env
    assert {"neighbour_points", "neighbour_valid"} <= set(env.observation_space.spaces)
    obs, info = env.reset(seed=3)
    assert env.observation_space.contains(obs)
    points = obs["neighbour_points"][obs["neighbour_valid"] > 0.5]
    for truth in info["objects"].values():
        d = np.linalg.norm(points[:, :2] - truth["position"][:2], axis=1).min()
        if truth["role"] == "distractor":
            assert d < 0.01  # its footprint is sampled: a point near its centre
        else:
            assert d > 0.005  # the target is not its own neighbour
    # one object on the table: the entry is off by default, and on it is empty
    plain = make_env("ScorbotGrasp-v0", pose="oracle", objects=["box"])
    assert "neighbour_points" not in plain.observation_space.spaces
    plain.close()
    alone = make_env("ScorbotGrasp-v0", pose="oracle", objects=["box"], neighbours=True)
    assert alone.reset(seed=0)[0]["neighbour_valid"].sum() == 0
    alone.close()


def test_check_env_with_neighbours_in_the_observation(oracle_clutter_env):
    from gymnasium.utils.env_checker import check_env

    with pytest.warns(UserWarning, match="different from the unwrapped"):  # a wrapper, on purpose
        check_env(oracle_clutter_env, skip_render_check=True)


def test_neighbours_need_a_source_that_reports_them():
    import gymnasium as gym

    env = gym.make("ScorbotGrasp-v0", objects=["box"])
    blind = FunctionPoseSource(lambda frame: None)
    with pytest.raises(ValueError, match="reports the other objects"):
        PoseEstimateObservation(env, blind, neighbours=True)
    env.close()


def test_a_seeded_clutter_episode_that_hit_a_neighbour_now_grasps(oracle_clutter_env):
    """Seed 5007 of the clutter benchmark (a golf ball beside a box and a foam brick): the
    fully open hand, blind to the neighbours, came down on the box and missed; choosing the
    closing line and opening to the ball's width, it grasps without knocking anything over."""
    env = oracle_clutter_env
    blind = ScriptedGraspPolicy.for_env(env, aperture_margin=None)
    blind_obs = {"neighbour_points", "neighbour_valid"}

    class WithoutNeighbours:  # the controller of before: the entry hidden from it
        replans = 0

        def reset(self, obs, info=None):
            blind.reset({k: v for k, v in obs.items() if k not in blind_obs}, info)

        def act(self, obs):
            return blind.act({k: v for k, v in obs.items() if k not in blind_obs})

    before = run_episode(env, WithoutNeighbours(), seed=5007)
    assert before.object_name == "golf_ball" and not before.success
    policy = ScriptedGraspPolicy.for_env(env)
    after = run_episode(env, policy, seed=5007)
    assert after.success, after.failure_cause
    assert after.extra["distractors_knocked_over"] == 0
    assert policy.chosen_grasp.clearance > 0 and policy.aperture < HAND.max_opening


def test_alone_on_the_table_the_hand_opens_fully_as_before():
    """Without neighbours in the observation the plan and the open hand are what they were
    (the shipped residual policy adds its correction to this controller)."""
    env = make_env("ScorbotGrasp-v0", pose="oracle", objects=["large_marker"])
    policy = ScriptedGraspPolicy.for_env(env)
    obs, info = env.reset(seed=0)
    policy.reset(obs, info)
    assert policy.aperture is None and policy.chosen_grasp.slide == 0.0
    assert policy.act(obs)[5] == 1.0  # the gripper command: fully open
    env.close()
