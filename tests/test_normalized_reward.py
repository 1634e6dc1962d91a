"""The normalised dense reward (``reward_type="normalized_dense"``, and ``"normalized_pregrasp"``
with its pre-grasp stage): its documented arithmetic,
checked on the real env (bounds, success against never finishing, the reach slope where
episodes start, what a collision costs)."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

import scorbot_gym  # noqa: F401  (registers the envs)
from scorbot_gym.envs.factory import make_env
from scorbot_gym.policies.scripted import ScriptedGraspPolicy
from scorbot_gym.rl import hyperparams as hparams
from scorbot_gym.tasks.grasp import (
    NORMALIZED_REWARD_TERMS,
    NORMALIZED_SHAPING_MAX,
    PREGRASP_OPENING,
    PREGRASP_REWARD_TERMS,
    REWARD_GAMMA,
    REWARD_TYPES,
    SUCCESS_BONUS,
    closing_progress,
    normalized_grasp_reward,
    normalized_shaping_max,
    pregrasp_progress,
)

W = NORMALIZED_SHAPING_MAX


def _terms_sum(info: dict) -> float:
    return sum(info[f"reward_{k}"] for k in NORMALIZED_REWARD_TERMS)


def _scripted_episode(seed: int, reward_type: str = "normalized_dense", **env_kwargs):
    env = make_env("ScorbotGraspCartesian-v0", pose="oracle", reward_type=reward_type, **env_kwargs)
    policy = ScriptedGraspPolicy.for_env(env)
    obs, info = env.reset(seed=seed)
    policy.reset(obs, info)
    rewards, infos = [], []
    for _ in range(150):
        obs, r, terminated, truncated, info = env.step(policy.act(obs))
        rewards.append(r)
        infos.append(info)
        if terminated or truncated:
            break
    env.close()
    return np.array(rewards), infos


def test_reward_types_agree_between_env_and_hyperparams():
    assert hparams.REWARD_TYPES == REWARD_TYPES
    assert hparams.DENSE_REWARD_GAMMA == REWARD_GAMMA  # repeated there too (PyYAML only)


def test_every_step_is_in_0_1_and_the_terms_sum_to_it():
    """A scripted success and a random episode: non-success steps pay at most w, the success
    step at least 1 - w, and the info terms add up to the reward."""
    rewards, infos = _scripted_episode(seed=0)
    assert infos[-1]["is_success"]
    assert all(0.0 <= r <= 1.0 for r in rewards)
    assert all(
        _terms_sum(i) == pytest.approx(r, abs=1e-12) for r, i in zip(rewards, infos, strict=True)
    )
    assert rewards[:-1].max() <= W and rewards[-1] >= 1.0 - W
    assert rewards[:-1].max() > 0.9 * W  # near the bound while holding: the bound is tight

    env = gym.make("ScorbotGrasp-v0", object_name="box", reward_type="normalized_dense")
    _, info = env.reset(seed=1)
    assert {k for k in info if k.startswith("reward_")} == {
        f"reward_{k}" for k in NORMALIZED_REWARD_TERMS
    }
    rng = np.random.default_rng(1)
    for _ in range(60):
        _, r, terminated, truncated, info = env.step(rng.uniform(-1, 1, 6))
        assert 0.0 <= r <= W and _terms_sum(info) == pytest.approx(r, abs=1e-12)
        if terminated or truncated:
            break
    env.close()


def test_success_beats_any_way_of_not_finishing():
    """At gamma = 0.99 with the time limit bootstrapped (infinite horizon), never finishing is
    worth at most w / (1 - gamma) = 0.5; a success within 68 steps at least gamma^68 (1 - w).
    On a real scripted episode, from every step of its last 68 the remaining discounted return
    beats that bound. A learner with gamma 0.995 would break it (the documented limit)."""
    gamma = REWARD_GAMMA
    # the largest a non-success step can pay (best case of every stage) is w
    best, _ = normalized_grasp_reward(0.0, True, 1.0, 10.0, False, False, 0.05, 0.5)
    assert best == pytest.approx(W)
    never_finish = W / (1 - gamma)
    assert never_finish == pytest.approx(0.5)
    worst_success, _ = normalized_grasp_reward(1.0, False, 0.0, 0.0, True, True, 0.05, 0.5)
    assert worst_success == pytest.approx(1 - W)
    assert gamma**68 * (1 - W) > never_finish > gamma**69 * (1 - W)
    # at 0.995 the same reward lets never finishing (1.0) outweigh finishing now (0.995)
    assert W / (1 - 0.995) > 1 - W

    rewards, infos = _scripted_episode(seed=2)
    assert infos[-1]["is_success"]
    n = len(rewards)
    for t in range(max(0, n - 68), n):
        rest = rewards[t:]
        value = float(np.sum(gamma ** np.arange(len(rest)) * rest))
        assert value > never_finish
    # the old dense reward's arithmetic needed a 600 bonus; this one stays in [0, 1]
    assert SUCCESS_BONUS == pytest.approx(600.0)


def test_reach_has_a_usable_slope_where_episodes_start():
    """The median start distance (TCP to grasp point) is about 0.34 m; there the reach term
    keeps over 20 % of its maximum, and a 2 cm step towards the object is worth, as a share
    of a success, over 10 times what the old dense reward pays for it (measured: 19 times)."""
    distances = []
    gains = {}
    for reward_type in ("normalized_dense", "dense"):
        env = gym.make("ScorbotGraspCartesian-v0", object_name="box", reward_type=reward_type)
        gain = []
        for seed in range(9):
            env.reset(seed=seed)
            task, robot = env.unwrapped.task, env.unwrapped.robot
            gap = task.grasp_point_world() - robot.tcp_pos
            if reward_type == "dense":
                distances.append(float(np.linalg.norm(gap)))
            stay = np.array([0, 0, 0, 0, 0, 1.0])
            _, _, _, _, before = env.step(stay)
            toward = np.r_[gap / np.linalg.norm(gap), 0.0, 0.0, 1.0]
            _, _, _, _, after = env.step(toward)  # one step: up to 2 cm closer
            gain.append(after["reward_reach"] - before["reward_reach"])
        env.close()
        success = 1.0 if reward_type == "normalized_dense" else SUCCESS_BONUS
        gains[reward_type] = np.median(gain) / success
    median = float(np.median(distances))
    assert 0.25 < median < 0.45
    assert 1 - math.tanh(3.0 * median) > 0.2
    assert gains["normalized_dense"] > 0
    assert gains["normalized_dense"] > 10 * gains["dense"]


def test_a_collision_step_pays_nothing():
    """Pushing the TCP down from the start makes the arm collide: those steps pay 0 (the
    collision term takes back the step's shaping), where the dense reward still pays."""
    paid = {}
    for reward_type in ("normalized_dense", "dense"):
        env = gym.make("ScorbotGraspCartesian-v0", object_name="box", reward_type=reward_type)
        env.reset(seed=0)
        for _ in range(80):
            _, r, terminated, truncated, info = env.step(np.array([0, 0, -1.0, 0, 0, 1.0]))
            if info["failure_cause"] == "collision":
                break
        assert info["failure_cause"] == "collision"
        paid[reward_type] = (r, info)
        env.close()
    r, info = paid["normalized_dense"]
    assert info["reward_collision"] < 0
    shaping = sum(info[f"reward_{k}"] for k in ("reach", "grasp", "lift", "hold"))
    assert info["reward_collision"] == pytest.approx(-shaping)
    assert r == 0.0
    assert paid["dense"][0] > 0  # collisions cost nothing under the old reward


def test_pregrasp_progress_rewards_the_open_turned_vertical_hand_and_never_moving_closer_less():
    """The pre-grasp stage: heading (a half turn is the same grasp), verticality and an open
    hand (counted as open within PREGRASP_RADIUS of the grasp point), a third each, each falling
    linearly to 0 at a quarter turn; 1 while grasped."""
    q = math.pi / 2
    assert pregrasp_progress(0.3, 0.0, 0.0, PREGRASP_OPENING, False) == pytest.approx(1.0)
    assert pregrasp_progress(0.3, math.pi, 0.0, PREGRASP_OPENING, False) == pytest.approx(1.0)
    assert pregrasp_progress(0.3, -0.2, 0.0, PREGRASP_OPENING, False) == pytest.approx(
        pregrasp_progress(0.3, 0.2, 0.0, PREGRASP_OPENING, False)
    )
    assert pregrasp_progress(0.3, q, q, 0.0, False) == pytest.approx(0.0)
    assert pregrasp_progress(0.3, q, q, 0.0, True) == 1.0
    # each part a third: a 30-degree tilt past vertical costs a third of a third
    assert pregrasp_progress(0.3, 0.0, -q / 3, PREGRASP_OPENING, False) == pytest.approx(1 - 1 / 9)
    # the hovering failure measured from scratch: closed hand above the object
    assert pregrasp_progress(0.05, 0.0, 0.0, 0.0, False) == pytest.approx(2 / 3)
    # at the grasp point closing costs nothing
    assert pregrasp_progress(0.0, 0.0, 0.0, 0.0, False) == pytest.approx(1.0)
    # moving closer never lowers it, whatever the opening
    reaches = np.linspace(0.1, 0.0, 50)
    for opening in (0.0, 0.01, 0.03, 0.06):
        p = [pregrasp_progress(d, 0.3, 0.2, opening, False) for d in reaches]
        assert all(b >= a - 1e-12 for a, b in zip(p, p[1:], strict=False))
    # five stages: the bound of a non-success step stays w
    best, terms = normalized_grasp_reward(0.0, True, 1.0, 10.0, False, False, 0.05, 0.5, 1.0)
    assert best == pytest.approx(W) and set(terms) == set(PREGRASP_REWARD_TERMS)
    # a collision costs the approach's pay (reach and pre-grasp), not the grasp's or lift's
    hit, terms = normalized_grasp_reward(0.0, True, 1.0, 10.0, True, False, 0.05, 0.5, 1.0, 1.0)
    assert terms["collision"] == pytest.approx(-2 * W / 5) and hit == pytest.approx(3 * W / 5)
    far, _ = normalized_grasp_reward(0.3, False, 0.0, 0.0, True, False, 0.05, 0.5, 0.8, 0.0)
    assert far == pytest.approx(0.0)


def test_closing_near_the_grasp_point_pays_up_to_half_a_grasp():
    assert closing_progress(0.3, 0.0, True) == 1.0
    assert closing_progress(0.3, 0.0, False) == 0.0  # closed far away: nothing
    assert closing_progress(0.0, PREGRASP_OPENING, False) == 0.0  # open at the point: nothing
    assert closing_progress(0.0, 0.0, False) == pytest.approx(0.5)  # never as much as a grasp
    assert closing_progress(0.01, 0.03, False) == pytest.approx(0.5 * 0.5 * 0.5)
    # at the point, closing raises it; nearer, the same closing raises it more
    at = [closing_progress(0.005, o, False) for o in np.linspace(0.06, 0.0, 20)]
    assert all(b > a for a, b in zip(at, at[1:], strict=False))
    assert closing_progress(0.005, 0.02, False) > closing_progress(0.015, 0.02, False)


def test_the_scripted_pregrasp_pose_scores_full_on_the_real_env():
    """The scripted controller opens, turns the hand to the closing line and closes at the
    grasp point: on the real env its pre-grasp term is at the stage's maximum (w / 5) on most
    steps before the fingers close; every reward stays in [0, 1] with the terms summing to it."""
    rewards, infos = _scripted_episode(seed=0, reward_type="normalized_pregrasp")
    assert infos[-1]["is_success"]
    assert all(0.0 <= r <= 1.0 for r in rewards)
    for r, i in zip(rewards, infos, strict=True):
        assert sum(i[f"reward_{k}"] for k in PREGRASP_REWARD_TERMS) == pytest.approx(r, abs=1e-12)
    first_grasp = next(t for t, i in enumerate(infos) if i["grasped"])
    stage = W / 5
    before = np.array([i["reward_pregrasp"] for i in infos[10:first_grasp]])
    assert np.median(before) == pytest.approx(stage, rel=0.01)
    assert (before > 0.95 * stage).mean() > 0.8
    # a thin object (the marker): the grasp stage rises as the hand closes at
    # the point, before the fingers touch
    _, infos = _scripted_episode(0, "normalized_pregrasp", object_name="large_marker")
    first_grasp = next(t for t, i in enumerate(infos) if i["grasped"])
    closing = [i["reward_grasp"] for i in infos[first_grasp - 6 : first_grasp]]
    assert 0 < max(closing) <= 0.5 * stage and closing[-1] > closing[0]
    assert infos[first_grasp]["reward_grasp"] == pytest.approx(stage)
    assert rewards[:-1].max() <= W and rewards[-1] >= 1.0 - W


def test_reward_gamma_sets_the_shaping_and_keeps_the_bound():
    """Built for gamma 0.8 (``reward_gamma``), a step that does not succeed pays at most
    w = 0.1 and a success at least 0.9: never finishing is worth at most w / (1 - 0.8) = 0.5
    at that discount (and less at any smaller one), so a success now still beats it; on a
    real scripted episode every reward is in [0, 1], the terms sum to it, and the non-success
    steps reach close to the larger bound."""
    w = normalized_shaping_max(0.8)
    assert w == pytest.approx(0.1)
    best, _ = normalized_grasp_reward(0.0, True, 1.0, 10.0, False, False, 0.05, 0.5, 1.0, 1.0, w)
    worst_success, _ = normalized_grasp_reward(
        1.0, False, 0.0, 0.0, True, True, 0.05, 0.5, 0.0, 0.0, w
    )
    assert best == pytest.approx(w) and worst_success == pytest.approx(1 - w)
    for gamma in (0.5, 0.8):
        assert w / (1 - gamma) <= 0.5 < worst_success
    assert w / (1 - 0.9) > worst_success  # a learner with a larger discount: the bound breaks

    rewards, infos = _scripted_episode(0, "normalized_pregrasp", reward_gamma=0.8)
    assert infos[-1]["is_success"]
    assert rewards[:-1].max() <= w and rewards[:-1].max() > 0.9 * w and rewards[-1] >= 1 - w
    assert all(
        sum(i[f"reward_{k}"] for k in PREGRASP_REWARD_TERMS) == pytest.approx(r, abs=1e-12)
        for r, i in zip(rewards, infos, strict=True)
    )
    # the same episode at the default: every reward 20 times smaller until the success
    default, _ = _scripted_episode(0, "normalized_pregrasp")
    np.testing.assert_allclose(rewards[:-1], 20 * default[:-1], rtol=1e-9)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"reward_type": "dense", "reward_gamma": 0.8}, "applies to the normalised rewards"),
        ({"reward_type": "sparse", "reward_gamma": 0.8}, "applies to the normalised rewards"),
        ({"reward_type": "normalized_dense", "reward_gamma": 1.0}, r"discount in \(0, 1\)"),
        ({"reward_type": "normalized_dense", "reward_gamma": "high"}, r"discount in \(0, 1\)"),
        ({"reward_type": "normalized_dense", "reward_gamma": True}, r"discount in \(0, 1\)"),
    ],
)
def test_the_env_refuses_a_reward_gamma_it_cannot_use(kwargs, message):
    with pytest.raises(ValueError, match=message):
        gym.make("ScorbotGrasp-v0", object_name="box", **kwargs)


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"reward_gamma": 0.7}, "gamma 0.8 is above reward_gamma 0.7"),
        ({"reward_gamma": 0.9, "reward_type": "dense"}, "applies to the normalised rewards"),
        ({"reward_gamma": 1}, r"in \(0, 1\)"),
    ],
)
def test_hyperparams_check_reward_gamma_before_a_run(overrides, message):
    """A run's resolved set is refused where the reward would not keep a success above never
    finishing for its learner, or where reward_gamma has nothing to apply to."""
    with pytest.raises(ValueError, match=message):
        hparams.resolve("sac", False, {"gamma": 0.8, **overrides}, entry="scratch")
    ok = hparams.resolve("sac", False, {"gamma": 0.8, "reward_gamma": 0.8}, entry="scratch")
    assert ok["reward_gamma"] == 0.8
