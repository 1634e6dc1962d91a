"""Disturbances that move the object, the grasp-pose filter, and the estimated-pose overlay."""

import gymnasium as gym
import numpy as np
import pytest

import scorbot_gym  # noqa: F401  (registers the ids)
from scorbot_gym.evaluation.video import draw_pose, record_episode
from scorbot_gym.policies import ScriptedGraspPolicy
from scorbot_gym.policies.pose_filter import GraspPoseFilter
from scorbot_gym.tasks.disturbance import ObjectPush, ObjectSlide, make_disturbance


def _object_track(disturbance, seed=4, steps=40):
    env = gym.make("ScorbotGrasp-v0", objects=["box"], disturbance=disturbance)
    env.reset(seed=seed)
    track, infos = [], []
    for _ in range(steps):  # the arm holds still: only the disturbance moves the object
        _, _, _, _, info = env.step(np.r_[np.zeros(5), 1.0])
        track.append(info["object_pose"]["position"].copy())
        infos.append(info.get("disturbance"))
    env.close()
    return np.array(track), infos


def test_push_moves_the_object_once_at_a_seeded_step():
    track, infos = _object_track("push")
    jumps = np.flatnonzero(np.linalg.norm(np.diff(track[:, :2], axis=0), axis=1) > 0.01)
    assert len(jumps) == 1
    info = infos[-1]
    assert info["applied"] and 0.02 - 1e-9 <= info["shift_m"] <= 0.05 + 1e-9
    assert jumps[0] + 2 == info["step"]  # track[i] is after step i + 1
    assert 15 <= abs(info["turn_deg"]) <= 45
    again, _ = _object_track("push")
    np.testing.assert_array_equal(track, again)  # same seed, same push


def test_slide_moves_steadily_and_stays_in_the_workspace():
    track, infos = _object_track(ObjectSlide(speed_m_s=(0.01, 0.01)), steps=30)
    steps = np.linalg.norm(np.diff(track[:, :2], axis=0), axis=1)
    assert np.all(steps < 0.002) and infos[-1]["travelled_m"] > 0.005
    env = gym.make("ScorbotGrasp-v0", objects=["box"])
    (x0, x1), (y0, y1) = env.unwrapped.sim.workspace_xy_bounds
    assert np.all((track[:, 0] >= x0 - 1e-9) & (track[:, 0] <= x1 + 1e-9))
    assert np.all((track[:, 1] >= y0 - 1e-9) & (track[:, 1] <= y1 + 1e-9))


def test_disturbance_off_by_default_and_bad_specs_rejected():
    _, infos = _object_track(None, steps=2)
    assert infos == [None, None]
    with pytest.raises(ValueError, match="unknown disturbance 'shove'; valid: none, push"):
        make_disturbance("shove")
    with pytest.raises(ValueError, match="distance_m must be"):
        ObjectPush(distance_m=(0.05, 0.01))


def test_filter_averages_noise_and_follows_a_confirmed_move():
    rng = np.random.default_rng(0)
    f = GraspPoseFilter(confirm=3)
    truth = np.array([0.3, 0.1, 0.8])
    restarts = [
        f.update(truth + np.r_[rng.normal(0, 0.005, 2), 0], rng.normal(0, 0.05)) for _ in range(20)
    ]
    assert restarts[0] and not any(restarts[1:])
    assert np.linalg.norm(f.point - truth) < 0.004 and abs(f.yaw) < 0.04
    assert not f.update(truth + [0.2, 0, 0], 0.0)  # one outlier is not a move
    moved = truth + [0.05, 0.0, 0.0]
    assert [f.update(moved, 0.5) for _ in range(3)] == [False, False, True]
    np.testing.assert_allclose(f.point, moved)
    assert np.isclose(f.yaw, 0.5)


def test_filter_wraps_the_closing_yaw_at_a_half_turn():
    f = GraspPoseFilter()
    f.update(np.zeros(3), np.pi / 2 - 0.01)
    assert not f.update(np.zeros(3), -np.pi / 2 + 0.01)  # the same grasp, turned half a turn
    assert abs(abs(f.yaw) - np.pi / 2) < 0.02


def test_wrist_takes_the_nearest_roll_for_a_closing_line():
    from scorbot_gym.robot.kinematics import JOINT_HIGH, JOINT_LOW, ArmKinematics

    kin = ArmKinematics()
    q, _ = kin.ik(np.array([0.28, -0.05, 0.9]), -np.pi / 2, np.zeros(5))
    for yaw in np.linspace(-np.pi, np.pi, 13):
        for near in (-3.0, -1.4, 0.0, 1.5, 3.0):
            q[4] = kin.roll_for_closing_yaw(q, yaw, near=near)
            assert JOINT_LOW[4] <= q[4] <= JOINT_HIGH[4]
            diff = (kin.closing_yaw(q) - yaw + np.pi / 2) % np.pi - np.pi / 2
            assert abs(diff) < 1e-6  # the same closing line
            for other in (q[4] - np.pi, q[4] + np.pi):  # the other roll: further, or out of range
                assert (
                    abs(other - near) >= abs(q[4] - near)
                    or not JOINT_LOW[4] <= other <= JOINT_HIGH[4]
                )


def test_roll_tolerance_must_be_a_positive_angle():
    for bad in (0.0, -0.1, float("nan")):
        with pytest.raises(ValueError, match="roll_tolerance must be a positive angle"):
            ScriptedGraspPolicy(object_name="box", roll_tolerance=bad)


def test_a_push_across_the_half_turn_does_not_swing_the_wrist_over_the_object():
    """Seed 1002: the can's closing direction is 179 deg, the push turns it by -21 deg. Wrapped
    into [-90, 90) the new wrist roll lay a half turn away, and the fingers, still turning,
    landed on the can (dropped); the nearest roll turns the wrist 21 deg and grasps."""
    from scorbot_gym.evaluation.rollout import RolloutConfig

    config = RolloutConfig(pose="oracle", disturbance="push", objects=("potted_meat_can",))
    env = config.make_env()
    policy = config.make_policy(env)
    obs, info = env.reset(seed=1002)
    policy.reset(obs, info)
    rolls = []
    for _ in range(150):
        obs, _, terminated, truncated, info = env.step(policy.act(obs))
        rolls.append(float(obs["joint_pos"][4]))
        if terminated or truncated:
            break
    env.close()
    assert info["disturbance"]["applied"] and abs(info["disturbance"]["turn_deg"]) > 15
    assert info["is_success"], info["failure_cause"]
    after_push = np.array(rolls[info["disturbance"]["step"] - 1 :])
    assert np.abs(after_push - after_push[0]).max() < np.deg2rad(40)  # was a ~160 deg swing


def test_noisy_estimates_every_step_still_grasp_with_the_filter():
    from scorbot_gym.evaluation.rollout import RolloutConfig, run_rollout

    noise = {"yaw_sigma_deg": 10.0, "pos_sigma_m": 0.01}
    config = RolloutConfig(pose="noisy", noise=noise, objects=("box",), episodes=2, seed=1)
    summary, _ = run_rollout(config)
    assert summary["success_rate"] == 1.0


def test_overlay_draws_axes_where_the_object_is(tmp_path):
    env = scorbot_gym.make_env(
        pose="oracle",
        objects=["box"],
        render_mode="rgb_array",
        render_camera="top",
        render_width=160,
        render_height=120,
    )
    obs, _ = env.reset(seed=0)
    frame = env.render()
    cam = env.unwrapped.camera_model("top", 160, 120)
    drawn = draw_pose(frame, cam, obs["object_pos"], np.eye(3))
    changed = np.argwhere(np.any(drawn != frame, axis=-1))
    u, v = cam.project(obs["object_pos"][None])[0]
    assert len(changed) > 20
    assert np.min(np.linalg.norm(changed[:, ::-1] - [u, v], axis=1)) < 3
    result, n = record_episode(
        env, ScriptedGraspPolicy.for_env(env), 0, tmp_path / "e.gif", overlay=True
    )
    assert n == result.steps + 1 and (tmp_path / "e.gif").read_bytes()[:3] == b"GIF"
