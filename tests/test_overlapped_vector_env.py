"""``OverlappedVectorEnv``: env 0 steps in the calling process, the others in workers. It must be
indistinguishable from Gymnasium's ``SyncVectorEnv`` over the same env functions: observations,
rewards, flags and infos in env order, seeds ``seed + i``, autoreset, partial resets."""

from __future__ import annotations

import functools

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

from scorbot_gym import OverlappedVectorEnv, pin_env_fns
from scorbot_gym.envs.overlapped import _merge_infos

IMAGE = {"cameras": ["top"], "image_width": 64, "image_height": 48}
# a short time limit, so that the rollouts below cross an autoreset
MAKE = functools.partial(
    gym.make, "scorbot_gym:ScorbotGrasp-v0", object_name="tomato_soup_can", max_episode_steps=4
)
WORKERS = {"shared_memory": True, "context": "spawn"}


def _assert_infos_equal(a: dict, b: dict) -> None:
    assert sorted(a) == sorted(b)
    for key in a:
        if isinstance(a[key], dict):
            _assert_infos_equal(a[key], b[key])
        elif a[key].dtype == object:
            assert list(a[key]) == list(b[key]), key
        else:
            np.testing.assert_array_equal(a[key], b[key], err_msg=key)


def _assert_same(first: tuple, second: tuple) -> None:
    for x, y in zip(first[:-1], second[:-1], strict=True):
        if isinstance(x, dict):
            for key in x:
                np.testing.assert_array_equal(x[key], y[key], err_msg=key)
        else:
            np.testing.assert_array_equal(x, y)
    _assert_infos_equal(first[-1], second[-1])


@pytest.mark.slow
def test_steps_like_sync_vector_env_through_autoresets_with_images():
    fns = [functools.partial(MAKE, **IMAGE)] * 3
    overlapped = OverlappedVectorEnv(pin_env_fns(fns), **WORKERS)
    sync = gym.vector.SyncVectorEnv(fns)
    try:
        assert overlapped.num_envs == 3 and len(overlapped.processes) == 2
        assert overlapped.observation_space == sync.observation_space
        assert overlapped.action_space == sync.action_space
        _assert_same(overlapped.reset(seed=5), sync.reset(seed=5))
        assert overlapped.np_random_seed == sync.np_random_seed == (5, 6, 7)
        overlapped.action_space.seed(5)
        ended = 0
        for _ in range(10):  # the time limit ends every episode at steps 4 and 9
            action = overlapped.action_space.sample()
            a, b = overlapped.step(action), sync.step(action)
            assert overlapped.observation_space.contains(a[0])
            _assert_same(a, b)
            ended += int(a[3].sum())
        assert ended == 6  # two episodes per env ended, and the next steps reset them
        assert a[0]["top_rgb"].any()  # rendered images, not empty shared buffers
    finally:
        overlapped.close()
        sync.close()


@pytest.mark.slow
def test_same_step_autoreset_and_partial_resets_match_sync_vector_env():
    for mode in (AutoresetMode.SAME_STEP, AutoresetMode.DISABLED):
        overlapped = OverlappedVectorEnv([MAKE] * 2, autoreset_mode=mode, **WORKERS)
        sync = gym.vector.SyncVectorEnv([MAKE] * 2, autoreset_mode=mode)
        try:
            assert overlapped.metadata["autoreset_mode"] == mode
            _assert_same(overlapped.reset(seed=[1, 2]), sync.reset(seed=[1, 2]))
            overlapped.action_space.seed(1)
            for _ in range(4):
                action = overlapped.action_space.sample()
                a, b = overlapped.step(action), sync.step(action)
                if mode == AutoresetMode.SAME_STEP:
                    assert a[-1].keys() == b[-1].keys()
                    np.testing.assert_array_equal(a[0]["joint_pos"], b[0]["joint_pos"])
                else:
                    _assert_same(a, b)
            if mode == AutoresetMode.DISABLED:  # reset env 1 only: env 0 keeps its last observation
                for mask in ([False, True], [True, False]):
                    mask = np.array(mask)
                    a = overlapped.reset(seed=[3, 4], options={"reset_mask": mask})
                    b = sync.reset(seed=[3, 4], options={"reset_mask": mask.copy()})
                    for key in a[0]:
                        np.testing.assert_array_equal(a[0][key], b[0][key], err_msg=key)
        finally:
            overlapped.close()
            sync.close()


def test_call_get_attr_set_attr_reach_every_env_in_order():
    overlapped = OverlappedVectorEnv([MAKE] * 2, **WORKERS)
    try:
        overlapped.reset(seed=0)
        assert overlapped.get_attr("object_names") == (("tomato_soup_can",),) * 2
        overlapped.set_attr("custom_tag", ["here", "worker"])
        assert overlapped.get_attr("custom_tag") == ("here", "worker")
        overlapped.set_attr("custom_tag", "all")
        assert overlapped.call("get_wrapper_attr", "custom_tag") == ("all", "all")
        with pytest.raises(ValueError, match="one per env"):
            overlapped.set_attr("custom_tag", ["only one"])
        bad = overlapped.action_space.sample()
        bad[0, 0] = np.nan  # env 0, here, rejects it while the worker steps its own action
        with pytest.raises(ValueError):
            overlapped.step(bad)
        obs, *_ = overlapped.step(overlapped.action_space.sample())  # still usable
        assert overlapped.observation_space.contains(obs)
        with pytest.raises(ValueError, match="one per env"):
            overlapped.reset(seed=[1, 2, 3])
        with pytest.raises(ValueError, match="shape \\(2,\\)"):
            overlapped.reset(options={"reset_mask": np.array([True])})
        with pytest.raises(ValueError, match="resets no env"):
            overlapped.reset(options={"reset_mask": np.array([False, False])})
    finally:
        overlapped.close()
    assert all(not p.is_alive() for p in overlapped.processes)


def test_bad_construction_is_one_clear_error():
    with pytest.raises(ValueError, match="at least 2 env functions"):
        OverlappedVectorEnv([MAKE])
    with pytest.raises(ValueError, match="valid: shared_memory, context"):
        OverlappedVectorEnv([MAKE] * 2, copy=False)
    with pytest.raises(ValueError, match="observation spaces differ"):
        OverlappedVectorEnv([MAKE, functools.partial(MAKE, **IMAGE)], **WORKERS)


def test_infos_merge_in_env_order_where_only_some_envs_report_a_key():
    here = {"cause": np.array(["timeout"], dtype=object), "_cause": np.array([True])}
    workers = {
        "held": np.array([0.5, 0.0]),
        "_held": np.array([True, False]),
        "nested": {"k": np.array([[1, 2], [3, 4]]), "_k": np.array([True, True])},
        "_nested": np.array([True, True]),
    }
    merged = _merge_infos(here, 1, workers, 2)
    assert list(merged["cause"]) == ["timeout", None, None]
    assert merged["_cause"].tolist() == [True, False, False]
    np.testing.assert_array_equal(merged["held"], [0.0, 0.5, 0.0])
    assert merged["_held"].tolist() == [False, True, False]
    np.testing.assert_array_equal(merged["nested"]["k"], [[0, 0], [1, 2], [3, 4]])
    assert merged["nested"]["_k"].tolist() == [False, True, True]
    assert merged["_nested"].tolist() == [False, True, True]
