"""Vector envs: ``scorbot_gym.make_vec_env`` and Gymnasium's own ``make_vec`` with images."""

from __future__ import annotations

import os

import gymnasium as gym
import numpy as np
import pytest

import scorbot_gym
from scorbot_gym.envs.vector import _EnvFactory

IMAGE = {"cameras": ["top"], "image_width": 64, "image_height": 48}


def _roll(vec: gym.vector.VectorEnv, steps: int = 3) -> tuple[dict, dict, list[dict]]:
    obs, reset_info = vec.reset(seed=3)
    assert vec.observation_space.contains(obs)
    vec.action_space.seed(3)
    infos = []
    for _ in range(steps):
        obs, reward, terminated, truncated, info = vec.step(vec.action_space.sample())
        assert vec.observation_space.contains(obs)
        assert reward.shape == terminated.shape == truncated.shape == (vec.num_envs,)
        infos.append(info)
    return obs, reset_info, infos


def test_make_vec_env_async_with_image_steps_inside_its_space():
    vec = scorbot_gym.make_vec_env("ScorbotGrasp-v0", 2, object_name="tomato_soup_can", **IMAGE)
    try:
        assert isinstance(vec, gym.vector.AsyncVectorEnv)
        obs, reset_info, infos = _roll(vec)
        assert obs["top_rgb"].shape == (2, 48, 64, 3) and obs["top_rgb"].dtype == np.uint8
        assert obs["top_rgb"].any()  # rendered, not an empty shared buffer
        # calibration comes with the reset (fixed cameras), not with every step
        assert reset_info["camera_params"]["top"]["K"].shape == (2, 3, 3)
        assert all("camera_params" not in info for info in infos)
    finally:
        vec.close()


def test_gymnasium_make_vec_async_shared_memory_with_image():
    vec = gym.make_vec(
        "ScorbotGrasp-v0",
        2,
        vectorization_mode="async",
        vector_kwargs={"shared_memory": True},
        object_name="tomato_soup_can",
        **IMAGE,
    )
    try:
        obs, _, _ = _roll(vec, steps=2)
        assert obs["top_rgb"].shape == (2, 48, 64, 3)
    finally:
        vec.close()


def test_sync_and_async_give_the_same_observations():
    kw = {"object_name": "tomato_soup_can"}
    sync = scorbot_gym.make_vec_env("ScorbotGrasp-v0", 2, "sync", **kw)
    asyn = scorbot_gym.make_vec_env("ScorbotGrasp-v0", 2, "async", max_concurrency=1, **kw)
    try:
        a, _, _ = _roll(sync)
        b, _, _ = _roll(asyn)
        for key in a:
            np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    finally:
        sync.close()
        asyn.close()


def test_factory_sets_render_threads_only_in_workers(monkeypatch):
    monkeypatch.delenv("LP_NUM_THREADS", raising=False)
    factory = _EnvFactory("ScorbotGrasp-v0", {"object_name": "tomato_soup_can"}, 1)
    factory().close()  # in the building process: its settings are left alone
    assert "LP_NUM_THREADS" not in os.environ
    factory.parent_pid = -1  # as seen from a worker process
    factory().close()
    assert os.environ["LP_NUM_THREADS"] == "1"


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"num_envs": 0}, "num_envs"),
        ({"num_envs": 2, "vectorization_mode": "ray"}, "vectorization_mode"),
        ({"num_envs": 2, "render_threads": -1}, "render_threads"),
        ({"num_envs": 2, "max_concurrency": 0}, "max_concurrency"),
    ],
)
def test_bad_arguments_raise(kwargs, match):
    with pytest.raises(ValueError, match=match):
        scorbot_gym.make_vec_env("ScorbotGrasp-v0", **kwargs)
