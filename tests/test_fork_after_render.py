"""A process that has rendered can fork vector-env workers that render (issue 35, item 8).

Mesa's EGL display does not survive a fork (its rasterizer threads stay in the parent), so a
forked worker used to deadlock on its first frame. The GL state is now released just before the
fork and rebuilt on the next frame; where it cannot be (a display opened by someone else), the
child refuses to render with a one-line error instead of hanging.
"""

from __future__ import annotations

import functools
import multiprocessing
import subprocess
import sys
import textwrap

import gymnasium as gym
import numpy as np
import pytest

import scorbot_gym  # noqa: F401  (registers the ids)
from scorbot_gym import _gl

IMAGE = {"object_name": "box", "cameras": ["top"], "image_width": 64, "image_height": 48}
TIMEOUT_S = 120  # a deadlocked worker never answers: fail instead of hanging the suite

pytestmark = pytest.mark.skipif(
    "fork" not in multiprocessing.get_all_start_methods(), reason="needs the fork start method"
)


def _reset_within_timeout(vec: gym.vector.AsyncVectorEnv, seed: int) -> dict:
    vec.reset_async(seed=seed)
    obs, _ = vec.reset_wait(timeout=TIMEOUT_S)  # multiprocessing.TimeoutError on a deadlock
    return obs


@pytest.mark.slow
def test_forked_workers_render_after_the_parent_stepped_a_camera_env_and_a_sync_vector_env():
    make = functools.partial(gym.make, "ScorbotGrasp-v0", **IMAGE)
    env = make()
    env.reset(seed=0)
    before = env.step(np.zeros(6, np.float32))[0]["top_rgb"]
    sync = gym.vector.SyncVectorEnv([make, make])
    expected, _ = sync.reset(seed=3)
    sync.step(sync.action_space.sample())
    forked = gym.vector.AsyncVectorEnv([make, make], context="fork")
    try:
        obs = _reset_within_timeout(forked, seed=3)
        np.testing.assert_array_equal(obs["top_rgb"], expected["top_rgb"])
        assert obs["top_rgb"].any()
    finally:
        forked.close(terminate=True)
    # The parent's contexts were released for the fork and are rebuilt: the same pixels.
    env.reset(seed=0)
    np.testing.assert_array_equal(env.step(np.zeros(6, np.float32))[0]["top_rgb"], before)
    np.testing.assert_array_equal(sync.reset(seed=3)[0]["top_rgb"], expected["top_rgb"])
    sync.close()
    env.close()


def test_a_child_forked_with_a_foreign_display_open_refuses_to_render_in_one_line():
    """A display opened by another library (here a ``mujoco.Renderer`` of the user's) is not
    ours to close: the forked worker says to use spawn instead of deadlocking."""
    script = textwrap.dedent(
        f"""
        import functools, gymnasium as gym, mujoco, scorbot_gym
        renderer = mujoco.Renderer(mujoco.MjModel.from_xml_string("<mujoco/>"), 8, 8)
        renderer.render()
        make = functools.partial(gym.make, "ScorbotGrasp-v0", **{IMAGE!r})
        vec = gym.vector.AsyncVectorEnv([make, make], context="fork")
        try:
            vec.reset(seed=0)
        except Exception as err:
            print(type(err).__name__, str(err))
        vec.close(terminate=True)
        """
    )
    done = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=TIMEOUT_S
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip() == f"RenderingUnavailableError {_gl.FORK_HINT}"
    assert "\n" not in _gl.FORK_HINT
