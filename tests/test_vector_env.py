"""Vector envs through Gymnasium's own ``make_vec``: async with images in shared memory, and
the camera calibration sent at reset only (the per-step info stays small)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import scorbot_gym  # noqa: F401  (registers the ids)

IMAGE = {"cameras": ["top"], "image_width": 64, "image_height": 48}
# spawn: a forked child inherits the parent's GL and thread state (earlier tests render), which
# can deadlock EGL in the child; see the README's note on vector envs.
ASYNC = {
    "vectorization_mode": "async",
    "vector_kwargs": {"shared_memory": True, "context": "spawn"},
}


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


@pytest.mark.slow
def test_async_make_vec_with_image_steps_inside_its_space():
    vec = gym.make_vec("ScorbotGrasp-v0", 2, **ASYNC, object_name="tomato_soup_can", **IMAGE)
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


def _assert_same_rollouts(first: gym.vector.VectorEnv, second: gym.vector.VectorEnv) -> None:
    """Roll both vector envs alike and compare their observations; closes both."""
    try:
        a, _, _ = _roll(first)
        b, _, _ = _roll(second)
        for key in a:
            np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    finally:
        first.close()
        second.close()


@pytest.mark.slow
def test_sync_and_async_give_the_same_observations():
    kw = {"object_name": "tomato_soup_can"}
    sync = gym.make_vec("ScorbotGrasp-v0", 2, vectorization_mode="sync", **kw)
    _assert_same_rollouts(sync, gym.make_vec("ScorbotGrasp-v0", 2, **ASYNC, **kw))


def test_calibration_at_reset_matches_camera_params():
    env = gym.make("ScorbotGrasp-v0", object_name="tomato_soup_can", **IMAGE)
    try:
        _, info = env.reset(seed=0)
        params = env.unwrapped.camera_params("top")
        np.testing.assert_array_equal(info["camera_params"]["top"]["K"], params["K"])
        _, _, _, _, info = env.step(env.action_space.sample())
        assert "camera_params" not in info
        assert env.unwrapped.camera_model("top").width == 64  # still there, on request
    finally:
        env.close()


def test_camera_on_the_arm_sends_its_calibration_every_step():
    """The eye-in-hand camera moves with the arm: a wrapper needs its extrinsics at every step,
    the fixed cameras' only at reset."""
    cameras = {**IMAGE, "cameras": ("top", "eye_in_hand")}
    env = gym.make("ScorbotGrasp-v0", object_name="tomato_soup_can", **cameras)
    try:
        _, info = env.reset(seed=0)
        assert set(info["camera_params"]) == {"top", "eye_in_hand"}
        before = info["camera_params"]["eye_in_hand"]["world_from_camera"]
        for _ in range(5):
            _, _, _, _, info = env.step(np.ones(env.action_space.shape))
        assert set(info["camera_params"]) == {"eye_in_hand"}
        after = info["camera_params"]["eye_in_hand"]["world_from_camera"]
        np.testing.assert_array_equal(
            after, env.unwrapped.camera_params("eye_in_hand")["world_from_camera"]
        )
        assert np.linalg.norm(after[:3, 3] - before[:3, 3]) > 1e-3  # the arm moved it
    finally:
        env.close()


@pytest.mark.slow
def test_pinned_workers_run_on_their_cores_and_match_unpinned():
    """``pin_env_fns``: worker i on core i % cores (checked from outside, in /proc), the main
    process left unpinned, and the observations the same as unpinned workers give."""
    import functools
    import os

    import pytest

    from scorbot_gym import pin_env_fns

    allowed = sorted(os.sched_getaffinity(0))
    make = functools.partial(
        gym.make, "scorbot_gym:ScorbotGrasp-v0", object_name="tomato_soup_can", **IMAGE
    )
    fns = pin_env_fns([make] * 3)
    assert [f.core for f in fns] == [allowed[i % len(allowed)] for i in range(3)]
    pinned = gym.vector.AsyncVectorEnv(fns[:2], shared_memory=True, context="spawn")
    cores = [os.sched_getaffinity(p.pid) for p in pinned.processes]
    assert sorted(os.sched_getaffinity(0)) == allowed  # the dummy env did not pin us
    plain = gym.vector.AsyncVectorEnv([make] * 2, shared_memory=True, context="spawn")
    _assert_same_rollouts(pinned, plain)
    assert cores == [{f.core} for f in fns[:2]]
    with pytest.raises(ValueError, match="cores this process may use"):
        pin_env_fns([make], cores=[max(allowed) + 1])
    with pytest.raises(ValueError, match="cores"):
        pin_env_fns([make], cores=[])
    with pytest.raises(ValueError, match="one env function per worker"):
        pin_env_fns([])
