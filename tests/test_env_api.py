"""The Gymnasium contract: check_env, spaces, determinism, rendering, bad input."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from scorbot_gym import ENV_IDS, ScorbotGraspEnv

SMALL = {"image_width": 64, "image_height": 48}


@pytest.mark.parametrize("env_id", sorted(ENV_IDS))
def test_check_env_every_registered_id(env_id):
    env = gym.make(env_id, object_name="foam_brick")
    check_env(env.unwrapped, skip_render_check=True)
    env.close()


@pytest.mark.parametrize("action_type", ["joint", "cartesian"])
def test_check_env_with_cameras_and_render(action_type):
    env = gym.make(
        "ScorbotGrasp-v0",
        action_type=action_type,
        object_name="box",
        cameras=["top"],
        image_types=("rgb", "depth"),
        render_mode="rgb_array",
        render_width=64,
        render_height=48,
        **SMALL,
    )
    check_env(env.unwrapped)
    env.close()


def test_make_with_module_prefix():
    env = gym.make("scorbot_gym:ScorbotGrasp-v0", object_name="box")
    assert env.unwrapped.spec.id == "ScorbotGrasp-v0"
    env.close()


def test_observation_hides_object_pose_unless_asked(joint_env):
    obs, info = joint_env.reset(seed=0)
    assert set(obs) == {"joint_pos", "joint_vel", "gripper_opening", "ee_pos", "ee_quat"}
    assert {"position", "quaternion"} <= set(info["object_pose"])
    env = gym.make("ScorbotGrasp-v0", object_name="box", observe_object_pose=True)
    obs, info = env.reset(seed=0)
    np.testing.assert_allclose(obs["object_pos"], info["object_pose"]["position"])


def test_image_shapes_and_dtypes():
    env = gym.make(
        "ScorbotGrasp-v0",
        object_name="box",
        cameras=["top", "side"],
        image_types=("rgb", "depth"),
        render_mode="depth_array",
        render_camera="overview",
        render_width=80,
        render_height=60,
        **SMALL,
    )
    obs, _ = env.reset(seed=1)
    for cam in ("top", "side"):
        assert obs[f"{cam}_rgb"].shape == (48, 64, 3) and obs[f"{cam}_rgb"].dtype == np.uint8
        assert obs[f"{cam}_depth"].shape == (48, 64, 1)
        assert obs[f"{cam}_depth"].dtype == np.float32
        assert obs[f"{cam}_rgb"].std() > 5  # a real picture, not a blank buffer
    frame = env.render()
    assert frame.shape == (60, 80) and frame.dtype == np.float32 and frame.min() > 0
    assert env.observation_space.contains(obs)
    env.close()


def _rollout(env, seed, n=25):
    obs, _ = env.reset(seed=seed)
    env.action_space.seed(seed)
    traj = [obs]
    for _ in range(n):
        obs, *_ = env.step(env.action_space.sample())
        traj.append(obs)
    return traj


def test_same_seed_same_trajectory_and_images():
    env = gym.make("ScorbotGrasp-v0", cameras=["top"], **SMALL)
    a, b = _rollout(env, 7), _rollout(env, 7)
    c = _rollout(env, 8)
    for oa, ob in zip(a, b, strict=True):
        for k in oa:
            np.testing.assert_array_equal(oa[k], ob[k])
    assert not np.array_equal(a[-1]["joint_pos"], c[-1]["joint_pos"])
    env.close()


def test_rendering_does_not_change_physics():
    plain = gym.make("ScorbotGrasp-v0", object_name="tennis_ball")
    seen = gym.make(
        "ScorbotGrasp-v0",
        object_name="tennis_ball",
        cameras=["top", "side"],
        render_mode="rgb_array",
        render_width=64,
        render_height=48,
        **SMALL,
    )
    ta = _rollout(plain, 3)
    obs, _ = seen.reset(seed=3)
    seen.action_space.seed(3)
    tb = [obs]
    for _ in range(25):
        obs, *_ = seen.step(seen.action_space.sample())
        seen.render()
        tb.append(obs)
    for oa, ob in zip(ta, tb, strict=True):
        np.testing.assert_array_equal(oa["joint_pos"], ob["joint_pos"])
        np.testing.assert_array_equal(oa["ee_pos"], ob["ee_pos"])


def test_nan_and_inf_actions_raise(joint_env):
    joint_env.reset(seed=0)
    for bad in (np.nan, np.inf, -np.inf):
        a = np.zeros(6, np.float32)
        a[2] = bad
        with pytest.raises(ValueError, match="NaN or inf"):
            joint_env.step(a)


def test_wrong_action_shape_raises(joint_env):
    joint_env.reset(seed=0)
    with pytest.raises(ValueError, match=r"shape \(6,\)"):
        joint_env.unwrapped.step(np.zeros(5))


def test_out_of_range_actions_are_clipped():
    env_a = gym.make("ScorbotGrasp-v0", object_name="box").unwrapped
    env_b = gym.make("ScorbotGrasp-v0", object_name="box").unwrapped
    env_a.reset(seed=0)
    env_b.reset(seed=0)
    big = np.array([5.0, -7.0, 3.0, -2.0, 9.0, -4.0])
    oa, *_ = env_a.step(big)
    ob, *_ = env_b.step(np.clip(big, -1, 1))
    np.testing.assert_array_equal(oa["joint_pos"], ob["joint_pos"])


def test_unknown_object_lists_valid_names():
    with pytest.raises(KeyError, match="valid objects: .*tomato_soup_can"):
        gym.make("ScorbotGrasp-v0", object_name="teapot")


def test_unknown_camera_lists_valid_names():
    with pytest.raises(ValueError, match="valid cameras: top, side, overview"):
        gym.make("ScorbotGrasp-v0", object_name="box", cameras=["ceiling"])


def test_bad_keyword_values_raise():
    with pytest.raises(ValueError, match="action_type"):
        gym.make("ScorbotGrasp-v0", action_type="torque")
    with pytest.raises(ValueError, match="render_mode"):
        ScorbotGraspEnv(render_mode="human")
    with pytest.raises(ValueError, match="image_types"):
        ScorbotGraspEnv(image_types=("normals",))
    with pytest.raises(ValueError, match="reward_type"):
        gym.make("ScorbotGrasp-v0", reward_type="shaped")


def test_blow_up_ends_episode_as_unstable():
    env = gym.make("ScorbotGrasp-v0", object_name="box")
    env.reset(seed=0)
    data = env.unwrapped.sim.data
    data.qvel[:] = 1e30  # a state no integrator survives
    obs, reward, terminated, truncated, info = env.step(np.zeros(6, np.float32))
    assert truncated and not terminated
    assert info["failure_cause"] == "unstable" and not info["is_success"]
    assert all(np.all(np.isfinite(v)) for v in obs.values())


def test_timeout_reports_a_failure_cause():
    env = gym.make("ScorbotGrasp-v0", object_name="box", max_episode_steps=5)
    env.reset(seed=0)
    for _ in range(5):
        _, _, terminated, truncated, info = env.step(np.r_[np.zeros(5), 1.0].astype(np.float32))
    assert truncated and not terminated
    assert info["failure_cause"] == "timeout" and not info["is_success"]
    assert env.spec.max_episode_steps == 5
    assert gym.make("ScorbotGrasp-v0", object_name="box").spec.max_episode_steps == 150


def test_sparse_reward_is_zero_without_success():
    env = gym.make("ScorbotGrasp-v0", object_name="box", reward_type="sparse")
    env.reset(seed=0)
    _, reward, *_ = env.step(np.zeros(6, np.float32))
    assert reward == 0.0
