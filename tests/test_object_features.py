"""What a learned policy is told about the object: the grasp frame, derived from any mesh."""

from __future__ import annotations

import json

import numpy as np
import pytest

from scorbot_gym import make_env
from scorbot_gym.policies.imitation import ImitationPolicy, n_features
from scorbot_gym.policies.object_features import (
    N_GRASP_FRAME,
    grasp_frame_features,
    n_object_features,
    object_name,
)
from scorbot_gym.policies.scripted import ScriptedGraspPolicy
from scorbot_gym.rl.imitation import ImitationConfig, train_imitation

pytestmark = pytest.mark.rl


@pytest.fixture(scope="module")
def banana_env():
    env = make_env("ScorbotGraspCartesian-v0", pose="oracle", objects=["banana", "box"])
    yield env
    env.close()


def test_the_grasp_frame_is_where_and_how_the_scripted_controller_grasps(banana_env):
    """The frame's grasp point and closing line are the controller's plan at the first
    estimate (the banana: asymmetric, so its closing line has one heading mod a half turn)."""
    names = tuple(banana_env.get_wrapper_attr("class_names"))
    for seed in range(6):
        obs, info = banana_env.reset(seed=seed, options={"object_name": "banana"})
        assert object_name(obs, names) == "banana"
        frame = grasp_frame_features(obs, "banana")
        expert = ScriptedGraspPolicy.for_env(banana_env)
        expert.reset(obs, info)
        np.testing.assert_allclose(frame[:3] + obs["ee_pos"], expert.grasp, atol=1e-6)
        q = obs["joint_pos"]
        doubled = 2.0 * (expert.closing_yaw - q[0])
        np.testing.assert_allclose([frame[4], frame[7]], [np.sin(doubled), np.cos(doubled)],
                                   atol=1e-6)  # fmt: skip
        assert 0.0 < frame[10] < 0.1 and 0.0 < frame[11] < 0.3  # width, height: a banana's


def test_no_estimate_or_no_identity_gives_zeros(banana_env):
    obs, _ = banana_env.reset(seed=0)
    placeholder = {**obs, "object_quat": np.zeros(4), "object_pos": np.zeros(3)}
    assert not grasp_frame_features(placeholder, "banana").any()
    assert not grasp_frame_features(obs, None).any()
    assert object_name({**obs, "object_class": np.zeros(2)}, ("banana", "box")) is None


def test_sizes_and_bad_names():
    assert n_object_features("class", 11) == 11
    assert n_object_features("grasp_frame", 11) == N_GRASP_FRAME
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
