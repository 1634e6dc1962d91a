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
