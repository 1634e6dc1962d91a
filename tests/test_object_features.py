"""What a learned policy is told about the object: the grasp frame, derived from any mesh."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from scorbot_gym import make_env
from scorbot_gym.policies.imitation import ImitationPolicy, n_features
from scorbot_gym.policies.object_features import (
    grasp_frame_view,
    n_object_features,
    object_name,
)
from scorbot_gym.policies.scripted import ScriptedGraspPolicy, yaw_from_quat
from scorbot_gym.rl.imitation import ImitationConfig, train_imitation

pytestmark = pytest.mark.rl


@pytest.fixture(scope="module")
def banana_env():
    env = make_env("ScorbotGraspCartesian-v0", pose="oracle", objects=["banana", "box"])
    yield env
    env.close()


def test_the_grasp_frame_is_where_and_how_the_scripted_controller_grasps(banana_env):
    """The pose the network reads is the controller's plan at the first estimate: the grasp
    point, and the closing line as the heading (the banana: asymmetric, so one line)."""
    names = tuple(banana_env.get_wrapper_attr("class_names"))
    for seed in range(6):
        obs, info = banana_env.reset(seed=seed, options={"object_name": "banana"})
        assert object_name(obs, names) == "banana"
        view = grasp_frame_view(obs, "banana")
        expert = ScriptedGraspPolicy.for_env(banana_env)
        expert.reset(obs, info)
        np.testing.assert_allclose(view["object_pos"], expert.grasp, atol=1e-6)
        turn = yaw_from_quat(view["object_quat"]) - expert.closing_yaw
        assert abs(np.sin(turn)) < 1e-6  # the same line (a half turn is the same grasp)
        assert view["joint_pos"] is obs["joint_pos"]  # the rest is the observation's


def test_no_estimate_or_no_identity_leaves_the_observation(banana_env):
    obs, _ = banana_env.reset(seed=0)
    placeholder = {**obs, "object_quat": np.zeros(4), "object_pos": np.zeros(3)}
    assert grasp_frame_view(placeholder, "banana") is placeholder
    assert grasp_frame_view(obs, None) is obs
    assert object_name({**obs, "object_class": np.zeros(2)}, ("banana", "box")) is None


def test_sizes_and_bad_names():
    assert n_object_features("class", 11) == 11
    assert n_object_features("grasp_frame", 11) == 0  # it replaces the pose, adds nothing
    with pytest.raises(
        ValueError, match=r"object_features must be one of \('class', 'grasp_frame'\)"
    ):
        ImitationConfig(object_features="shape")


def test_a_grasp_frame_policy_trains_round_trips_and_needs_the_identity(banana_env, tmp_path):
    config = ImitationConfig(
        demos=2, dagger_rounds=0, fit_steps=20, hidden=(16,), object_features="grasp_frame"
    )
    policy, _ = train_imitation(banana_env, config)
    assert policy.net.n_inputs == n_features(2, config.history, "grasp_frame")
    policy.save(tmp_path / "p")
    meta = json.loads((tmp_path / "p" / "policy.json").read_text())
    assert meta["object_features"] == "grasp_frame"
    loaded = ImitationPolicy.load(tmp_path / "p").bind(banana_env)
    obs, info = banana_env.reset(seed=9)
    loaded.reset(obs, info)
    np.testing.assert_allclose(loaded.act(obs), policy.act(obs))
    blind = make_env(
        "ScorbotGraspCartesian-v0", pose="oracle", objects=["box"], include_class=False
    )
    try:
        with pytest.raises(ValueError, match="needs its identity"):
            loaded.bind(blind)
    finally:
        blind.close()
    meta["object_features"] = "shape"
    (tmp_path / "p" / "policy.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match="object_features must be 'class' or 'grasp_frame'"):
        ImitationPolicy.load(tmp_path / "p")


def test_a_policy_saved_before_the_key_is_told_the_class():
    from scorbot_gym.policies.imitation import SHIPPED_LEARNED_POLICY

    meta = json.loads((SHIPPED_LEARNED_POLICY / "policy.json").read_text())
    assert "object_features" not in meta
    assert ImitationPolicy.load(SHIPPED_LEARNED_POLICY).object_features == "class"
    assert ImitationConfig().object_features == "class"


def test_a_grasp_frame_policy_reads_the_frame_of_an_object_it_never_trained_on(
    banana_env, tmp_path
):
    """Its env keeps the env's own classes, so a new object has an identity and a frame (with
    the training classes pinned, a new object's one-hot would be empty)."""
    config = ImitationConfig(
        demos=1, dagger_rounds=0, fit_steps=5, hidden=(8,), object_features="grasp_frame"
    )
    policy, _ = train_imitation(banana_env, config)  # trained on banana and box
    assert "classes" not in policy.env_kwargs()
    kw = {k: v for k, v in policy.env_kwargs().items() if k != "env_id"}
    env = make_env("ScorbotGraspCartesian-v0", pose="oracle", objects=["cylinder"], **kw)
    try:
        policy.bind(env)
        obs, info = env.reset(seed=2)
        view = policy.view(obs)
        assert view is not obs  # the frame, not the object's own pose
        expert = ScriptedGraspPolicy.for_env(env)
        expert.reset(obs, info)
        np.testing.assert_allclose(view["object_pos"], expert.grasp, atol=1e-6)
    finally:
        env.close()
    pinned = make_env(
        "ScorbotGraspCartesian-v0", pose="oracle", objects=["cylinder"], classes=["banana", "box"]
    )
    try:
        obs, _ = pinned.reset(seed=2)
        # what pinning the classes did: no identity, no frame; said once and counted
        with pytest.warns(RuntimeWarning, match="no identity"):
            assert policy.bind(pinned).view(obs) is obs
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            policy.view(obs)
        assert policy.frame_fallbacks == 2
    finally:
        pinned.close()


def test_the_sb3_grasp_frame_observation_is_the_frame_relative_to_the_hand(banana_env):
    """What an SB3 policy with ``object_features: grasp_frame`` reads: the frame in place of
    the pose, the frame minus the TCP, doubled headings, no class; a flag says when there is
    no frame (no identity), so the fallback to the object's own pose is an input."""
    from scorbot_gym.policies.object_features import (
        GRASP_FRAME_ENTRIES,
        GraspFrameObservation,
        grasp_frame_observation,
    )

    names = tuple(banana_env.get_wrapper_attr("class_names"))
    obs, _ = banana_env.reset(seed=4, options={"object_name": "banana"})
    out = grasp_frame_observation(obs, names)
    view = grasp_frame_view(obs, "banana")
    assert "object_class" not in out
    np.testing.assert_allclose(out["object_pos"], view["object_pos"])
    np.testing.assert_allclose(out["grasp_offset"], view["object_pos"] - obs["ee_pos"], atol=1e-6)
    yaw = yaw_from_quat(view["object_quat"])
    assert out["grasp_heading"][0] == pytest.approx(np.sin(2 * yaw), abs=1e-6)
    assert out["grasp_heading"][4] == pytest.approx(np.cos(2 * yaw), abs=1e-6)
    assert out["grasp_frame_valid"][0] == 1.0
    anonymous = grasp_frame_observation({**obs, "object_class": np.zeros(2)}, names)
    assert anonymous["grasp_frame_valid"][0] == 0.0
    np.testing.assert_allclose(anonymous["object_pos"], obs["object_pos"])
    wrapped = GraspFrameObservation(banana_env)
    sizes = {k: s.shape[0] for k, s in banana_env.observation_space.spaces.items()}
    del sizes["object_class"]
    assert {k: s.shape[0] for k, s in wrapped.observation_space.spaces.items()} == {
        **sizes,
        **GRASP_FRAME_ENTRIES,
    }
    obs, _ = wrapped.reset(seed=5)
    assert set(obs) == set(wrapped.observation_space.spaces)
    assert wrapped.observation_space.contains(
        {k: np.asarray(v, wrapped.observation_space[k].dtype) for k, v in obs.items()}
    )
    no_class = make_env(
        "ScorbotGraspCartesian-v0", pose="oracle", objects=["box"], include_class=False
    )
    try:
        with pytest.raises(ValueError, match="needs the object_class one-hot"):
            GraspFrameObservation(no_class)
    finally:
        no_class.close()


def test_the_reward_reaches_for_the_grasp_frame_of_every_catalogue_object():
    """What the scratch policy reads and what its reward pays for agree: the normalised
    reward's reach target (the task's grasp point) is the grasp frame's point, every object."""
    from scorbot_gym.policies.object_features import grasp_frame_observation

    env = make_env("ScorbotGraspCartesian-v0", pose="oracle")
    try:
        names = tuple(env.get_wrapper_attr("class_names"))
        for name in names:
            obs, _ = env.reset(seed=7, options={"object_name": name})
            target = env.unwrapped.task.grasp_point_world()  # ground truth, for the test only
            frame = grasp_frame_observation(obs, names)["object_pos"]
            np.testing.assert_allclose(frame, target, atol=0.003, err_msg=name)
    finally:
        env.close()
