"""Gymnasium environments and their registration."""

from __future__ import annotations

import gymnasium as gym

from scorbot_gym.envs.grasp import ScorbotGraspEnv

ENV_IDS = {
    "ScorbotGrasp-v0": {"action_type": "joint"},
    "ScorbotGraspCartesian-v0": {"action_type": "cartesian"},
}


def register_envs() -> None:
    """Register every scorbot-gym id (idempotent).

    The time limit lives in the env (``max_episode_steps=150``, 6 s at 25 Hz) rather than in a
    ``TimeLimit`` wrapper, so that a truncated episode can say why it failed.
    """
    for env_id, kwargs in ENV_IDS.items():
        if env_id in gym.registry:
            continue
        gym.register(
            id=env_id,
            entry_point="scorbot_gym.envs.grasp:ScorbotGraspEnv",
            kwargs=kwargs,
        )


__all__ = ["ENV_IDS", "ScorbotGraspEnv", "register_envs"]
