"""The world is graspable: the scripted policy with the true pose lifts every object."""

import numpy as np
import pytest

from scorbot_gym.envs.factory import make_env
from scorbot_gym.evaluation import run_episode, run_episodes, summarize, wilson_interval
from scorbot_gym.objects import CATALOGUE
from scorbot_gym.policies import RandomPolicy, ScriptedGraspPolicy


@pytest.fixture(scope="module")
def envs():
    made = {
        t: make_env(
            "ScorbotGraspCartesian-v0" if t == "cartesian" else "ScorbotGrasp-v0", pose="oracle"
        )
        for t in ("joint", "cartesian")
    }
    yield made
    for env in made.values():
        env.close()


def _scripted(env, seed, name):
    return run_episode(env, ScriptedGraspPolicy.for_env(env), seed, {"object_name": name})


@pytest.mark.parametrize("name", sorted(CATALOGUE))
def test_scripted_oracle_grasps_every_object(envs, name):
    results = [_scripted(envs["joint"], seed, name) for seed in (0, 1)]
    assert all(r.success for r in results), results
    assert all(r.failure_cause is None for r in results)


@pytest.mark.slow
def test_scripted_oracle_cartesian_actions(envs):
    for name in ("tomato_soup_can", "banana", "large_marker"):
        assert _scripted(envs["cartesian"], 3, name).success


def test_user_added_object_is_grasped(user_object):
    env = make_env(pose="oracle", object_name="user_block")
    assert run_episode(env, ScriptedGraspPolicy.for_env(env), 0).success
    env.close()


def test_random_policy_fails_with_a_cause(envs):
    env = envs["joint"]
    r = run_episode(env, RandomPolicy(env.action_space), 0, {"object_name": "box"})
    assert not r.success and r.failure_cause in ("missed", "collision", "timeout", "dropped")


def test_episodes_record_where_the_hand_ended_and_came_closest(envs):
    """``info["grasp_distance"]`` (ground truth, for scoring) is the TCP's distance to the
    grasp point; an episode records its last and its smallest value: the scripted grasp closes
    at the point, a random policy stays far from it."""
    env = envs["cartesian"]
    _, info = env.reset(seed=3, options={"object_name": "box"})
    base = env.unwrapped
    truth = np.linalg.norm(base.robot.tcp_pos - base.task.grasp_point_world())
    assert info["grasp_distance"] == pytest.approx(truth) and info["grasp_distance"] > 0.1
    won = _scripted(env, 0, "box")
    assert won.success and won.extra["closest_grasp_distance_m"] < 0.01
    r = run_episode(env, RandomPolicy(env.action_space), 0, {"object_name": "box"})
    lost = r.extra
    assert lost["closest_grasp_distance_m"] <= lost["final_grasp_distance_m"]
    assert lost["closest_grasp_distance_m"] > 0.05


def test_random_policy_episodes_are_reproducible(envs):
    env = envs["joint"]
    a = run_episode(env, RandomPolicy(env.action_space), 4, {"object_name": "box"})
    b = run_episode(env, RandomPolicy(env.action_space, seed=99), 4, {"object_name": "box"})
    assert a.total_reward == b.total_reward and a.steps == b.steps


def test_summary_counts_and_interval(envs):
    env = envs["joint"]
    policy = ScriptedGraspPolicy.for_env(env)
    results = run_episodes(env, policy, 3, seed=10, options={"object_name": "box"}, progress=False)
    s = summarize(results)
    assert s["episodes"] == 3 and s["success_rate"] == 1.0
    lo, hi = s["success_rate_ci95"]
    assert 0.4 < lo < 1.0 and hi == 1.0
    assert s["perception"]["valid_rate"] == 1.0 and s["perception"]["privileged"]
    assert np.isclose(wilson_interval(5, 10)[0], 0.2366, atol=1e-3)
    for n in range(1, 300):  # bounds hold the rate exactly (error bars never negative)
        assert wilson_interval(n, n)[1] == 1.0 and wilson_interval(0, n)[0] == 0.0


class _WrongUntilClosed:
    """An estimate 10 cm off along the table until the fingers first close (on nothing), then
    the truth: the pose source a re-grasp is for (a bad first estimate, a better one once the
    hand is out of the way)."""

    def __init__(self, env, offset=(0.0, 0.10, 0.0)):
        self.env, self.offset, self.closed = env, np.asarray(offset), False

    def _fix(self, obs):
        self.closed |= float(obs["gripper_opening"][0]) < 0.004
        if not self.closed:
            obs = {**obs, "object_pos": obs["object_pos"] + self.offset}
        return obs

    def reset(self, **kw):
        self.closed = False
        obs, info = self.env.reset(**kw)
        return self._fix(obs), info

    def step(self, action):
        obs, *rest = self.env.step(action)
        return (self._fix(obs), *rest)


@pytest.mark.parametrize("regrasps", [0, 1])
def test_the_scripted_controller_regrasps_after_closing_on_nothing(envs, regrasps):
    env = envs["cartesian"]
    wrong = _WrongUntilClosed(env)
    policy = ScriptedGraspPolicy.for_env(env, regrasps=regrasps)
    obs, info = wrong.reset(seed=3, options={"object_name": "box"})
    policy.reset(obs, info)
    for _ in range(env.spec.max_episode_steps):
        obs, _, terminated, truncated, info = wrong.step(policy.act(obs))
        if terminated or truncated:
            break
    assert wrong.closed, "the first grasp closed on nothing"
    assert policy.regrasp_count == regrasps
    assert info["is_success"] == bool(regrasps), info.get("failure_cause")
    if not regrasps:
        assert info["failure_cause"] == "missed"


def test_regrasps_must_be_a_count():
    with pytest.raises(ValueError, match="regrasps must be an integer >= 0"):
        ScriptedGraspPolicy(regrasps=-1)
