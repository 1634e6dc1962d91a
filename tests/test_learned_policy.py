"""The reward's arithmetic, imitation + DAgger, demonstrations as Minari datasets, and the
shipped stand-alone learned policy (issue 36, items 1, 2, 3, 5)."""

from __future__ import annotations

import inspect
import json
import math
import shutil

import numpy as np
import pytest

from scorbot_gym import make_env
from scorbot_gym.policies.imitation import SHIPPED_LEARNED_POLICY, ImitationPolicy
from scorbot_gym.policies.loading import load_policy, uses_scripted_controller
from scorbot_gym.policies.scripted import ScriptedGraspPolicy
from scorbot_gym.rl.imitation import (
    ExecutedActionExpert,
    ImitationConfig,
    _skeleton,
    collect_episodes,
    oracle_view,
    train_imitation,
)
from scorbot_gym.tasks.grasp import (
    REWARD_GAMMA,
    SHAPING_MAX,
    SUCCESS_BONUS,
    GraspTask,
    grasp_reward,
)

pytestmark = pytest.mark.rl

TINY = ImitationConfig(demos=2, dagger_rounds=1, dagger_episodes=1, fit_steps=20, hidden=(16,))


@pytest.fixture(scope="module")
def box_env():
    env = make_env("ScorbotGraspCartesian-v0", pose="oracle", objects=["box"])
    yield env
    env.close()


# --- 1. the reward ---------------------------------------------------------------------------


def test_success_is_worth_more_than_any_way_of_not_finishing():
    """Under the documented gamma, from any step at which the object is grasped, lifting and
    finishing beats collecting the largest shaping reward forever (holding just under the lift
    height with the time limit bootstrapped), whatever the episode looked like before."""
    gamma, lift_height, hold_time, dt = REWARD_GAMMA, 0.05, 0.5, 0.04
    defaults = inspect.signature(GraspTask).parameters
    assert defaults["lift_height"].default == lift_height
    assert defaults["hold_time"].default == hold_time
    best_step, _ = grasp_reward(0.0, True, 10 * lift_height, False, lift_height)
    assert best_step == pytest.approx(SHAPING_MAX)  # the documented bound is the real maximum
    just_under, _ = grasp_reward(0.0, True, 0.999 * lift_height, False, lift_height)
    hold_forever = just_under / (1 - gamma)  # ≈ 400: the old reward's trap
    never_finish_bound = SHAPING_MAX / (1 - gamma)  # any non-finishing continuation
    n_hold = math.ceil(hold_time / dt - 1e-9)
    held, _ = grasp_reward(0.0, True, lift_height, False, lift_height)
    done, terms = grasp_reward(0.0, True, lift_height, True, lift_height)
    succeed = sum(gamma**t * held for t in range(n_hold - 1)) + gamma ** (n_hold - 1) * done
    assert terms["success"] == SUCCESS_BONUS
    assert succeed > never_finish_bound >= hold_forever
    # the prefix before the grasp is shared by both continuations: still true k steps later
    for k in (1, 50, 149):
        assert gamma**k * succeed > gamma**k * never_finish_bound
    # and the old bonus of 10 failed this test: holding was worth more than finishing
    old_done = held + 10.0
    old = sum(gamma**t * held for t in range(n_hold - 1)) + gamma ** (n_hold - 1) * old_done
    assert old < hold_forever


def test_reward_terms_are_in_info_and_sum_to_the_reward(box_env):
    obs, info = box_env.reset(seed=0)
    assert all(info[f"reward_{k}"] == 0.0 for k in ("reach", "grasp", "lift", "success"))
    expert = ScriptedGraspPolicy.for_env(box_env)
    expert.reset(obs, info)
    for _ in range(5):
        obs, reward, *_, info = box_env.step(expert.act(obs))
        terms = [info[f"reward_{k}"] for k in ("reach", "grasp", "lift", "success")]
        assert reward == pytest.approx(sum(terms)) and terms[0] > 0


# --- 2. imitation and DAgger -----------------------------------------------------------------


def test_tiny_imitation_run_writes_a_loadable_policy_that_acts_in_the_action_space(
    box_env, tmp_path
):
    policy, record = train_imitation(box_env, TINY)
    assert record["demonstration_episodes"] == 2 and record["dagger_episodes"] == 1
    assert record["env_steps"] > 0 and len(record["rounds"]) == 2
    policy.save(tmp_path / "p")
    meta = json.loads((tmp_path / "p" / "policy.json").read_text())
    assert meta["uses_scripted_controller"] is False
    assert meta["history"] == {
        "previous_actions": 2,
        "gripper_commands": 20,
        "pose_window": 0,
        "pose_dispersion": False,
        "stall_steps": 0,
    }
    assert len(meta["normalization"]["mean"]) == policy.net.n_inputs
    loaded = load_policy(tmp_path / "p")
    assert isinstance(loaded, ImitationPolicy) and not uses_scripted_controller(loaded)
    loaded.bind(box_env)
    obs, info = box_env.reset(seed=3)
    loaded.reset(obs, info)
    for _ in range(3):
        a = loaded.act(obs)
        assert box_env.action_space.contains(a)
        np.testing.assert_allclose(a, policy.act(obs))  # same weights, same history
        obs, *_ = box_env.step(a)


@pytest.mark.parametrize("sync", [False, True])
def test_dagger_labels_are_the_scripted_controllers_actions_on_the_visited_states(box_env, sync):
    """With beta = 0 the learner drives; replaying the recorded (oracle) observations and the
    executed actions through a fresh scripted controller gives exactly the recorded labels."""
    learner = _skeleton(box_env, TINY)
    rng = np.random.default_rng(0)
    learner.net.weights = [
        rng.normal(0, 0.5, w.shape).astype(np.float32) for w in learner.net.weights
    ]
    (episode,) = collect_episodes(
        box_env, [7], learner=learner, beta=0.0, rng=rng, sync_expert=sync
    )
    assert not np.allclose(episode.actions, episode.labels[: len(episode)])  # learner acted
    scripted = ScriptedGraspPolicy.for_env(box_env)
    expert = ExecutedActionExpert(scripted) if sync else scripted
    classes = box_env.get_wrapper_attr("class_names")
    for t in range(len(episode) + 1):
        obs = {k: v[t] for k, v in episode.observations.items()}
        info = {
            "object_pose": {
                "position": episode.infos["object_position"][t],
                "quaternion": episode.infos["object_quaternion"][t],
            },
            "object_name": classes[int(episode.infos["object_class"][t])],
        }
        if t == 0:
            expert.reset(oracle_view(obs, info, classes), info)
        label = expert.act(oracle_view(obs, info, classes))
        np.testing.assert_array_equal(label, episode.labels[t])
        if sync and t < len(episode):
            expert.executed(episode.actions[t])


# --- 3. demonstrations as a Minari dataset ---------------------------------------------------


def test_demos_command_writes_a_minari_dataset_the_trainer_reads(tmp_path, monkeypatch, capsys):
    import minari

    from scorbot_gym.cli import main
    from scorbot_gym.rl.datasets import load_demonstrations

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    assert main(["demos", "--episodes", "2", "--seed", "4", "--out", "scorbot/grasp-test-v0"]) == 0
    assert "2 episodes" in capsys.readouterr().out
    ds = minari.load_dataset("scorbot/grasp-test-v0")
    assert ds.total_episodes == 2
    ep = next(ds.iterate_episodes())
    assert len(ep.actions) == len(ep.rewards) == len(ep.observations["object_pos"]) - 1
    assert {"pose_valid", "pose_age", "object_class", "joint_pos"} <= set(ep.observations)
    assert {"expert_action", "is_success", "object_position", "reward_success"} <= set(ep.infos)
    assert all(ds.action_space.contains(a) for a in ep.actions)
    episodes = load_demonstrations("scorbot/grasp-test-v0")
    assert [e.seed for e in episodes] == [4, 5]
    np.testing.assert_array_equal(episodes[0].actions, ep.actions)
    assert main(["demos", "--episodes", "1", "--out", "scorbot/grasp-test-v0"]) == 2  # exists


def test_dataset_keeps_the_camera_calibration_and_round_trips(tmp_path, monkeypatch):
    from scorbot_gym.rl.datasets import load_demonstrations, write_dataset

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    env = make_env(
        "ScorbotGraspCartesian-v0",
        pose="oracle",
        objects=["box"],
        cameras=["top"],
        image_width=64,
        image_height=48,
    )
    try:
        episodes = collect_episodes(env, [1], dart_sigma=0.2)
        write_dataset("scorbot/cams-v0", episodes, env, description="test")
        K = env.get_wrapper_attr("camera_params")("top")["K"]
    finally:
        env.close()
    (back,) = load_demonstrations("scorbot/cams-v0")
    np.testing.assert_allclose(back.infos["camera_top_K"][0], K)
    for k, v in episodes[0].observations.items():
        np.testing.assert_array_equal(back.observations[k], v)
    np.testing.assert_array_equal(back.labels, episodes[0].labels)
    np.testing.assert_array_equal(back.rewards, episodes[0].rewards)


# --- 5. the shipped stand-alone policy -------------------------------------------------------


def test_shipped_learned_policy_uses_no_controller_and_grasps_a_seeded_episode():
    from scorbot_gym.evaluation.rollout import RolloutConfig, run_rollout

    policy = load_policy("learned")
    assert isinstance(policy, ImitationPolicy) and not uses_scripted_controller(policy)
    assert not hasattr(policy, "base")
    assert uses_scripted_controller(load_policy("rl"))  # the residual says so
    summary, _ = run_rollout(RolloutConfig(policy="learned", episodes=1, seed=50_000))
    assert summary["successes"] == 1


@pytest.mark.parametrize("damage", ["weights", "json", "history", "algo"])
def test_a_corrupt_or_incompatible_policy_is_a_one_line_error(tmp_path, damage):
    path = tmp_path / "p"
    shutil.copytree(SHIPPED_LEARNED_POLICY, path)
    meta = json.loads((path / "policy.json").read_text())
    if damage == "weights":
        (path / "weights.npz").write_bytes(b"not a numpy archive")
    elif damage == "json":
        (path / "policy.json").write_text("{ truncated")
    elif damage == "history":
        meta["history"]["gripper_commands"] += 1
        (path / "policy.json").write_text(json.dumps(meta))
    else:
        meta["algo"] = "dqn"
        (path / "policy.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError) as exc:
        load_policy(path)
    assert "\n" not in str(exc.value) and str(path) in str(exc.value)


@pytest.mark.parametrize("keeps_close", [False, True])
def test_a_blocked_descent_is_labelled_close_until_the_learner_closes(box_env, keeps_close):
    """A learner that follows the labels but is held 3 cm above the grasp (a descent blocked on
    a rim) and never closes: the controller decides to close after its 2 s descent. With
    ``keeps_close`` every later label says close; without, the learner's open fingers send the
    controller back to a fresh descent, and close labels come one per 2 s."""
    expert = ExecutedActionExpert(ScriptedGraspPolicy.for_env(box_env), keeps_close=keeps_close)
    classes = box_env.get_wrapper_attr("class_names")
    obs, info = box_env.reset(seed=7)
    expert.reset(oracle_view(obs, info, classes), info)
    closing = []
    while True:
        label = expert.act(oracle_view(obs, info, classes))
        closing.append(bool(label[-1] < 0))
        action = label.copy()
        grasp = expert.base.grasp
        if grasp is not None and obs["ee_pos"][2] < grasp[2] + 0.03:
            action[2] = max(action[2], 0.0)  # blocked: never lower
        action[-1] = 1.0  # never closes
        expert.executed(action)
        obs, _, terminated, truncated, info = box_env.step(action)
        assert not terminated  # never grasped
        if truncated:  # the time limit
            break
    first = closing.index(True)
    after = np.mean(closing[first:])
    if keeps_close:
        assert after == 1.0
    else:
        assert 0 < after < 0.1


def test_expert_keeps_close_needs_the_synchronised_expert(box_env):
    from scorbot_gym.rl.pixel import PixelImitationConfig

    for make in (ImitationConfig, PixelImitationConfig):
        with pytest.raises(ValueError, match="expert_keeps_close needs sync_expert"):
            make(sync_expert=False, expert_keeps_close=True)
    with pytest.raises(ValueError, match="expert_keeps_close needs sync_expert"):
        collect_episodes(box_env, [0], expert_keeps_close=True)
    assert ImitationConfig().expert_keeps_close is False  # the shipped recipe's labeller


def test_a_run_with_labels_that_keep_closing_records_it(box_env):
    from dataclasses import replace

    config = replace(TINY, expert_keeps_close=True, history={"stall_steps": 10})
    policy, record = train_imitation(box_env, config)
    assert record["config"]["expert_keeps_close"] is True
    assert policy.meta["training"]["config"]["expert_keeps_close"] is True
    assert len(record["rounds"]) == 2  # BC, then its DAgger round with the new labeller
