"""Gymnasium environments and their registration.

The registration needs Gymnasium only: :class:`ScorbotGraspEnv` (and with it MuJoCo) is imported
when first used.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

import gymnasium as gym

if TYPE_CHECKING:
    from scorbot_gym.envs.grasp import ScorbotGraspEnv

MAX_EPISODE_STEPS = 150  # 6 s of simulated time at 25 Hz control

ENV_IDS = {
    "ScorbotGrasp-v0": {"action_type": "joint"},
    "ScorbotGraspCartesian-v0": {"action_type": "cartesian"},
}


def register_envs() -> None:
    """Register every scorbot-gym id (idempotent)."""
    for env_id, kwargs in ENV_IDS.items():
        if env_id in gym.registry:
            continue
        gym.register(
            id=env_id,
            # ScorbotGraspEnv, whose errors in a vector-env worker reach the main process
            entry_point="scorbot_gym.envs.worker:make_grasp_env",
            max_episode_steps=MAX_EPISODE_STEPS,
            kwargs=kwargs,
        )


def __getattr__(name: str):
    if name == "ScorbotGraspEnv":
        return importlib.import_module("scorbot_gym.envs.grasp").ScorbotGraspEnv
    raise AttributeError(f"module 'scorbot_gym.envs' has no attribute {name!r}")


__all__ = ["ENV_IDS", "ScorbotGraspEnv", "register_envs"]
