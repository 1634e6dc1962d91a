"""PoseEstimateObservation and the pose-source registry: spaces, holding, ages, seeding."""

import gymnasium as gym
import numpy as np
import pytest

from scorbot_gym.envs.factory import make_env
from scorbot_gym.perception import (
    PerceptionFrame,
    WorldPose,
    make_pose_source,
    pose_source_names,
    register_pose_source,
)
from scorbot_gym.perception.registry import _REGISTRY
from scorbot_gym.wrappers import MAX_AGE, PoseEstimateObservation


def _rollout(env, seed, steps=8):
    obs, info = env.reset(seed=seed)
    out = [(obs, info)]
    for _ in range(steps):
        obs, _, term, trunc, info = env.step(np.zeros(6, np.float32))
        out.append((obs, info))
    return out


def test_observation_space_holds_every_observation():
    env = make_env(pose="noisy_oracle", pose_kwargs={"dropout": 0.3}, object_name="banana")
    for obs, info in _rollout(env, 0, 20):
        assert env.observation_space.contains(obs)
        assert "perception" in info
    assert {"object_pos", "object_quat", "pose_valid", "pose_age", "object_class"} <= set(obs)
    env.close()


def test_estimate_every_holds_the_estimate_and_ages_it():
    env = make_env(pose="noisy_oracle", pose_kwargs={"pos_sigma_m": 0.01}, estimate_every=3)
    steps = _rollout(env, 1, 7)
    ages = [int(o["pose_age"][0]) for o, _ in steps]
    assert ages == [0, 1, 2, 0, 1, 2, 0, 1]
    estimated = [i["perception"]["estimated"] for _, i in steps]
    assert estimated == [True, False, False, True, False, False, True, False]
    # between estimates the held pose does not change
    np.testing.assert_array_equal(steps[1][0]["object_pos"], steps[0][0]["object_pos"])
    assert not np.array_equal(steps[3][0]["object_pos"], steps[0][0]["object_pos"])
    env.close()


def test_estimate_once_per_episode():
    env = make_env(pose="oracle", estimate_every=0, rotation="yaw")
    steps = _rollout(env, 2, 5)
    assert [int(o["pose_age"][0]) for o, _ in steps] == [0, 1, 2, 3, 4, 5]
    s, c = steps[0][0]["object_yaw"]
    assert np.isclose(s * s + c * c, 1.0)
    env.close()


def test_invalid_estimates_hold_the_last_valid_one():
    def flaky(frame: PerceptionFrame) -> WorldPose:
        if frame.step % 2:
            return WorldPose.invalid("odd step")
        return WorldPose(np.array([0.3, 0.0, 0.8]), np.array([1.0, 0, 0, 0]), True, 0.7)

    env = make_env(pose=make_pose_source("oracle"))  # any env; swap the source below
    wrapped = PoseEstimateObservation(env.env, make_pose_source(_registered(flaky)))
    steps = _rollout(wrapped, 0, 3)
    assert [o["pose_valid"][0] for o, _ in steps] == [1, 0, 1, 0]
    assert [o["pose_age"][0] for o, _ in steps] == [0, 1, 0, 1]
    np.testing.assert_allclose(steps[1][0]["object_pos"], [0.3, 0.0, 0.8])
    assert steps[1][0]["pose_confidence"][0] == pytest.approx(0.7)
    env.close()


def _registered(fn):
    register_pose_source("test_flaky", lambda: fn, overwrite=True)
    return "test_flaky"


def test_no_valid_estimate_yet_is_flagged_with_max_age():
    register_pose_source("test_blind", lambda: lambda frame: WorldPose.invalid("blind"))
    try:
        env = make_env(pose="test_blind")
        obs, info = env.reset(seed=0)
        assert obs["pose_valid"][0] == 0 and obs["pose_age"][0] == MAX_AGE
        assert env.observation_space.contains(obs)
        assert info["perception"]["estimated"] and not info["perception"]["valid"]
        env.close()
    finally:
        _REGISTRY.pop("test_blind")
        _REGISTRY.pop("test_flaky", None)


def test_noisy_oracle_is_seeded_and_records_errors():
    env = make_env(pose="noisy_oracle", pose_kwargs={"yaw_sigma_deg": 10.0, "pos_sigma_m": 0.02})
    a = [o["object_pos"].copy() for o, _ in _rollout(env, 5, 4)]
    b = [o["object_pos"].copy() for o, _ in _rollout(env, 5, 4)]
    np.testing.assert_array_equal(a, b)
    _, info = env.reset(seed=6)
    p = info["perception"]
    assert p["privileged"] and p["rot_err_deg"] > 0 and 0 < p["pos_err_cm"] < 10
    env.close()


def test_occluded_oracle_hides_the_object_while_the_hand_is_near():
    """The estimate is lost exactly while the hand is within this episode's distance (drawn
    from the range at reset, from the wrapper's seeded generator); otherwise it is the noisy
    oracle's. Bad ranges and an observation without the hand are one-line errors."""
    source = make_pose_source("occluded_oracle", pos_sigma_m=0.0, hide_distance_m=[0.1, 0.2])
    truth = {"position": np.array([0.3, 0.0, 0.78]), "quaternion": np.array([1.0, 0, 0, 0])}
    drawn = []
    for seed in range(20):
        source.reset(PerceptionFrame(truth=truth), np.random.default_rng(seed))
        drawn.append(source._hide)
        for height, hidden in ((0.09, True), (0.21, False)):
            ee = truth["position"] + [0.0, 0.0, height]
            est = source.estimate(PerceptionFrame({"ee_pos": ee}, truth=truth))
            assert est.valid is not hidden
            if hidden:
                assert "hidden by the hand" in est.reason
            else:
                np.testing.assert_allclose(est.position, truth["position"])
    assert 0.1 <= min(drawn) < max(drawn) <= 0.2
    with pytest.raises(ValueError, match="no ee_pos"):
        source.estimate(PerceptionFrame({}, truth=truth))
    for bad in ([0.2, 0.1], [0.1], [-0.1, 0.1], "0.1"):
        with pytest.raises(ValueError, match="hide_distance_m must be"):
            make_pose_source("occluded_oracle", hide_distance_m=bad)


def test_occluded_oracle_in_the_env_holds_the_last_estimate():
    """In the env the hand starts far from the object: never hidden at distance 0, always
    at 10 m (no estimate, pose_age at MAX_AGE, pose_valid 0)."""
    near = make_env(pose="occluded_oracle", pose_kwargs={"hide_distance_m": [0.0, 0.0]})
    assert all(o["pose_valid"][0] == 1 and o["pose_age"][0] == 0 for o, _ in _rollout(near, 3))
    near.close()
    far = make_env(pose="occluded_oracle", pose_kwargs={"hide_distance_m": [10.0, 10.0]})
    for obs, info in _rollout(far, 3):
        assert obs["pose_valid"][0] == 0 and obs["pose_age"][0] >= 1
        assert "hidden by the hand" in info["perception"]["reason"]
    far.close()


def test_registry_rejects_bad_names_and_lists_the_valid_ones():
    assert {"oracle", "noisy_oracle", "manifold"} <= set(pose_source_names())
    with pytest.raises(ValueError, match="registered: .*oracle"):
        make_pose_source("nonsense")
    with pytest.raises(ValueError, match="already registered"):
        register_pose_source("oracle", lambda: None)
    with pytest.raises(ValueError, match="dropout"):
        make_pose_source("noisy_oracle", dropout=1.5)


def test_missing_camera_is_a_clear_error(tmp_path):
    class NeedsTop:
        required_keys = ("top_rgb",)
        privileged = False

        def reset(self, frame, rng):
            pass

        def estimate(self, frame):
            return WorldPose.invalid("unused")

    with pytest.raises(ValueError, match="top_rgb.*cameras="):
        PoseEstimateObservation(gym.make("ScorbotGrasp-v0"), NeedsTop())


def test_passes_gymnasium_and_sb3_env_checkers():
    from gymnasium.utils.env_checker import check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env = make_env(
        pose="noisy_oracle", object_name="box", cameras=["top"], image_width=64, image_height=48
    )
    check_env(env, skip_render_check=True)
    sb3_check_env(env)
    env.close()


@pytest.mark.slow
def test_async_vector_env_with_the_wrapper():
    envs = gym.make_vec(
        "ScorbotGrasp-v0",
        num_envs=2,
        vectorization_mode="async",
        vector_kwargs={"context": "spawn"},  # see test_vector_env: forking a rendering parent
        wrappers=[lambda e: PoseEstimateObservation(e, "noisy_oracle", estimate_every=2)],
    )
    obs, info = envs.reset(seed=[0, 1])
    assert obs["object_pos"].shape == (2, 3) and obs["pose_age"].shape == (2, 1)
    obs, *_ = envs.step(np.zeros((2, 6), np.float32))
    assert np.all(obs["pose_age"] == 1)
    envs.close()


@pytest.mark.slow
def test_sync_vector_env_and_sb3_subproc_vec_env_with_the_wrapper():
    from stable_baselines3.common.vec_env import SubprocVecEnv

    envs = gym.make_vec(
        "ScorbotGrasp-v0",
        num_envs=2,
        vectorization_mode="sync",
        wrappers=[lambda e: PoseEstimateObservation(e, "oracle")],
    )
    obs, _ = envs.reset(seed=[0, 1])
    assert obs["pose_valid"].tolist() == [[1.0], [1.0]]
    envs.close()

    def factory(seed):
        return lambda: make_env(pose="noisy_oracle", object_name="box")

    vec = SubprocVecEnv([factory(0), factory(1)], start_method="spawn")
    vec.seed(3)
    obs = vec.reset()
    assert obs["object_pos"].shape == (2, 3)
    obs, _, _, infos = vec.step(np.zeros((2, 6), np.float32))
    assert all("perception" in i for i in infos) and obs["pose_age"].shape == (2, 1)
    vec.close()


def test_record_video_with_the_wrapper(tmp_path):
    env = make_env(
        pose="oracle", object_name="box", render_mode="rgb_array", render_width=96, render_height=72
    )
    env = gym.wrappers.RecordVideo(
        env, str(tmp_path), episode_trigger=lambda i: True, disable_logger=True
    )
    env.reset(seed=0)
    for _ in range(5):
        env.step(np.zeros(6, np.float32))
    env.close()
    assert list(tmp_path.glob("*.mp4"))
