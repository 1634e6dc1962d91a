"""The arm: servo tracking, inverse kinematics, gripper; and learning-library compatibility."""

import gymnasium as gym
import numpy as np
import pytest

from scorbot_gym.robot import JOINT_HIGH, JOINT_LOW, Robot
from scorbot_gym.sim import Simulation
from scorbot_gym.sim.arm import ARM_JOINTS, GRIPPER_MAX_OPENING, HOME_QPOS


@pytest.fixture(scope="module")
def robot():
    return Robot(Simulation("box"))


@pytest.mark.parametrize("joint", range(5))
def test_servo_step_response_tracks_without_oscillation(robot, joint):
    """A 0.3 rad step on one joint: settles within 0.5 s, overshoot under 10 %."""
    sim = robot.sim
    sim.reset()
    q0 = robot.joint_pos
    target = q0.copy()
    target[joint] += 0.3 if q0[joint] + 0.3 < JOINT_HIGH[joint] else -0.3
    robot.set_joint_targets(target)
    trace = []
    for _ in range(500):  # 1 s
        sim.step(1)
        trace.append(robot.joint_pos[joint])
    trace = np.array(trace)
    step = target[joint] - q0[joint]
    progress = (trace - q0[joint]) / step
    assert progress.max() < 1.10, f"{ARM_JOINTS[joint]} overshoots {progress.max() - 1:.1%}"
    assert np.all(np.abs(progress[250:] - 1.0) < 0.03), f"{ARM_JOINTS[joint]} has not settled"


def test_ik_reaches_a_tool_down_pose(robot):
    target = np.array([0.3, 0.05, robot.sim.table_height + 0.1])
    q, err = robot.kinematics.ik(target, -np.pi / 2, HOME_QPOS)
    assert err < 1e-3
    assert np.all(q >= JOINT_LOW - 1e-9) and np.all(q <= JOINT_HIGH + 1e-9)
    pos, R = robot.kinematics.forward(q)
    np.testing.assert_allclose(pos, target, atol=1e-3)
    np.testing.assert_allclose(R[:, 0], [0, 0, -1], atol=1e-3)  # tool axis points down


def test_wrist_roll_sets_the_closing_direction(robot):
    q, _ = robot.kinematics.ik(
        np.array([0.28, -0.05, robot.sim.table_height + 0.1]), -np.pi / 2, HOME_QPOS
    )
    for yaw in (-1.2, 0.0, 0.7):
        q[4] = robot.kinematics.roll_for_closing_yaw(q, yaw)
        diff = (robot.kinematics.closing_yaw(q) - yaw + np.pi / 2) % np.pi - np.pi / 2
        assert abs(diff) < 1e-6


def test_gripper_opens_and_closes_over_its_range(robot):
    sim = robot.sim
    sim.reset()
    for opening in (GRIPPER_MAX_OPENING, 0.0, 0.04):
        robot.set_gripper_target(opening)
        sim.step(300)
        assert abs(robot.gripper_opening - opening) < 2e-3


def test_stable_baselines3_learns_on_the_env():
    """The Dict observation works with SB3's MultiInputPolicy (a few PPO updates, no claim)."""
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_checker import check_env

    env = gym.make("ScorbotGrasp-v0", object_name="box", max_episode_steps=32)
    check_env(env.unwrapped)
    model = PPO(
        "MultiInputPolicy", env, n_steps=64, batch_size=32, n_epochs=1, seed=0, device="cpu"
    )
    model.learn(total_timesteps=128)
    obs, _ = env.reset(seed=0)
    action, _ = model.predict(obs, deterministic=True)
    assert env.action_space.contains(action)


def test_closed_form_ik_is_exact_and_keeps_the_branch(robot):
    """On reachable joint angles inside the limits, the closed form returns those angles (the
    elbow on its side, the base facing the same way) and its TCP lands on the target."""
    kin = robot.kinematics
    rng = np.random.default_rng(3)
    solved = 0
    for _ in range(300):
        q = rng.uniform(JOINT_LOW * 0.95, JOINT_HIGH * 0.95)
        if abs(q[2]) < 0.05:  # a straight elbow is on both sides
            continue
        pos, _ = kin.forward(q)
        q_init = q + rng.normal(0.0, 0.02, 5)
        q_init[2] = q[2]
        sol = kin.ik_closed_form(pos, q[1] + q[2] + q[3], q_init)
        if sol is None:  # only where the target is near the base axis (a branch change)
            assert np.hypot(*(pos[:2] - kin.base_pos[:2])) < 0.05
            continue
        solved += 1
        np.testing.assert_allclose(kin.forward(sol)[0], pos, atol=1e-9)
        np.testing.assert_allclose(sol[:4], q[:4], atol=1e-9)
        assert sol[4] == q_init[4]
    assert solved > 250


def test_closed_form_ik_leaves_the_hard_cases_to_the_least_squares(robot):
    kin = robot.kinematics
    q = np.array(HOME_QPOS)
    pos, _ = kin.forward(q)
    pitch = q[1] + q[2] + q[3]
    far = kin.base_pos + np.array([2.0, 0.0, 0.3])
    assert kin.ik_closed_form(far, pitch, q) is None  # out of reach
    # a pitch the wrist cannot take: the wrist would pass its limit
    assert kin.ik_closed_form(pos, pitch + 2.5, q) is None
    # the same target from the other elbow side is a jump of more than max_jump
    q_other = q.copy()
    q_other[2] = -q[2]
    assert kin.ik_closed_form(pos, pitch, q_other) is None


def test_closed_form_and_least_squares_agree_on_env_steps(robot):
    """The env's Cartesian step (targets 2 cm and 0.1 rad from the current pose): where the
    closed form answers, the damped least squares reach the same joint angles within their
    tolerance."""
    kin = robot.kinematics
    rng = np.random.default_rng(5)
    answered, diffs = 0, []
    for _ in range(300):
        q = np.array(HOME_QPOS) + rng.normal(0.0, 0.3, 5)
        q = np.clip(q, JOINT_LOW, JOINT_HIGH)
        pos = kin.forward(q)[0] + rng.uniform(-0.02, 0.02, 3)
        pitch = q[1] + q[2] + q[3] + rng.uniform(-0.1, 0.1)
        exact = kin.ik_closed_form(pos, pitch, q)
        if exact is None:
            continue
        answered += 1
        dls, err = kin.ik(pos, pitch, q, iterations=15)
        if err < 1e-4:
            diffs.append(np.abs(dls[:4] - exact[:4]).max())
    assert answered > 200 and len(diffs) > 200  # the rest: past a limit near home's elbow
    assert np.median(diffs) < 3e-4 and max(diffs) < 2e-3


def test_cartesian_ik_keyword_is_checked_and_used():
    with pytest.raises(ValueError, match=r"cartesian_ik must be one of \('closed_form', 'dls'\)"):
        gym.make("ScorbotGrasp-v0", action_type="cartesian", cartesian_ik="jacobian")
    a = np.array([0.5, -0.3, -0.8, 0.2, 0.1, 1.0])
    targets = {}
    for ik in ("closed_form", "dls"):
        env = gym.make(
            "ScorbotGrasp-v0", object_name="box", action_type="cartesian", cartesian_ik=ik
        )
        env.reset(seed=4)
        u = env.unwrapped
        q = u.robot.joint_pos
        targets[ik] = u._cartesian_target(q, a)
        if ik == "dls":
            pos = u.robot.tcp_pos + a[:3] * u.max_cartesian_step
            pitch = q[1] + q[2] + q[3] + a[3] * u.max_angle_step
            expected, _ = u.robot.kinematics.ik(pos, pitch, q, iterations=15)
            np.testing.assert_array_equal(targets[ik][:4], expected[:4])
        env.close()
    np.testing.assert_allclose(targets["closed_form"], targets["dls"], atol=2e-3)
