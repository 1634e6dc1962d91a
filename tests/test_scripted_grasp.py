"""The world is graspable: the scripted controller with the true pose lifts every object."""

import gymnasium as gym
import numpy as np
import pytest

from scorbot_gym.objects import CATALOGUE
from scorbot_gym.rollout import run_episode, run_episodes, summarize, wilson_interval


@pytest.fixture(scope="module")
def envs():
    made = {t: gym.make("ScorbotGrasp-v0", action_type=t) for t in ("joint", "cartesian")}
    yield made
    for env in made.values():
        env.close()


@pytest.mark.parametrize("name", sorted(CATALOGUE))
def test_scripted_oracle_grasps_every_object(envs, name):
    results = [run_episode(envs["joint"], seed, object_name=name) for seed in (0, 1)]
    assert all(r.success for r in results), results
    assert all(r.failure_cause is None for r in results)


def test_scripted_oracle_cartesian_actions(envs):
    for name in ("tomato_soup_can", "banana", "large_marker"):
        assert run_episode(envs["cartesian"], 3, object_name=name).success


def test_user_added_object_is_grasped(user_object):
    env = gym.make("ScorbotGrasp-v0", object_name="user_block")
    assert run_episode(env, 0).success
    env.close()


def test_random_policy_fails_with_a_cause(envs):
    r = run_episode(envs["joint"], 0, policy="random", object_name="box")
    assert not r.success and r.failure_cause in ("missed", "collision", "timeout", "dropped")


def test_summary_counts_and_interval(envs):
    results = run_episodes(envs["joint"], 3, seed=10, progress=False, object_name="box")
    s = summarize(results)
    assert s["episodes"] == 3 and s["success_rate"] == 1.0
    lo, hi = s["success_rate_ci95"]
    assert 0.4 < lo < 1.0 and hi == 1.0
    assert np.isclose(wilson_interval(5, 10)[0], 0.2366, atol=1e-3)
