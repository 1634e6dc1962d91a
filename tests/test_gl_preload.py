"""Rendering, then training, in one process with the CUDA build of torch (issue 35, item 1).

Mesa's llvmpipe puts the system's LLVM in the global symbol scope on the first frame; triton's
``libtriton.so`` (imported by ``torch._dynamo`` when SB3 builds its Adam optimiser) bundles its own
LLVM and, loaded after that frame, segfaults. ``scorbot_gym._gl.preload_bundled_llvm`` loads it
before the first GL context. The check needs a process of its own: the crash kills it.
"""

import importlib.util
import os
import subprocess
import sys
import textwrap

import pytest

RENDER_THEN_TRAIN = textwrap.dedent(
    """
    import gymnasium as gym
    import numpy as np

    import scorbot_gym

    env = gym.make("ScorbotGrasp-v0", cameras=["top"], image_width=64, image_height=48)
    obs, _ = env.reset(seed=0)
    assert obs["top_rgb"].std() > 1.0, "no frame was rendered"
    env.close()

    from stable_baselines3 import SAC

    model = SAC(
        "MlpPolicy", gym.make("Pendulum-v1"), learning_starts=0, batch_size=8,
        buffer_size=64, seed=0, device="cpu",
    )
    model.learn(total_timesteps=4)  # gradient steps: Adam updates after the first frame
    assert model.num_timesteps == 4
    print("trained after rendering")
    """
)


@pytest.mark.slow
@pytest.mark.skipif(
    importlib.util.find_spec("triton") is None,
    reason="triton is not installed (e.g. the CPU build of torch): no second LLVM to clash",
)
def test_training_after_rendering_does_not_crash_with_triton_installed():
    env = {**os.environ, "MUJOCO_GL": "egl"}
    proc = subprocess.run(
        [sys.executable, "-c", RENDER_THEN_TRAIN],
        capture_output=True,
        text=True,
        timeout=600,
        env=env,
    )
    assert proc.returncode == 0, (
        f"render-then-train exited with {proc.returncode} "
        f"({'SIGSEGV: the LLVM clash' if proc.returncode == -11 else 'error'}):\n"
        f"{proc.stderr[-3000:]}"
    )
    assert "trained after rendering" in proc.stdout


def test_preload_loads_the_installed_bundled_llvm_libraries_only():
    """The preload finds a library through its package's spec without importing the package."""
    from scorbot_gym import _gl

    before = set(sys.modules)
    loaded = _gl.preload_bundled_llvm()
    for package, relative in _gl.BUNDLED_LLVM_LIBRARIES:
        installed = importlib.util.find_spec(package) is not None
        assert any(p.endswith(relative) for p in loaded) == installed
        assert package in before or package not in sys.modules
