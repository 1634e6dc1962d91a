"""Gymnasium environments and their registration."""

from __future__ import annotations

import gymnasium as gym

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


__all__ = ["ENV_IDS", "ScorbotGraspEnv", "register_envs"]
