"""Residual RL on top of the scripted controller: ``action = clip(base(obs) + scale * a)``, where
``a`` corrects the arm's components (and the gripper's only with ``gripper=True``).

From-scratch SAC on this task was still at 0 % after 56k steps (about 20 minutes here): the
sparse part of the problem (close the fingers at the right moment, then lift) is found by
chance too rarely. A residual policy starts where the scripted controller is (the learned term
is zero-initialised, see :func:`scorbot_gym.rl.training.zero_init_actor`) and learns only a
correction, e.g. for the bias and jitter of an estimated pose.

The base controller reads observations only, so the wrapper runs inside ``SubprocVecEnv``
workers. The base's action is added to the observation as ``base_action`` (the learned term
sees what it corrects); the controller's internal phase is not observed.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from scorbot_gym.policies.base import Policy
from scorbot_gym.policies.sb3 import residual_action  # the one definition, shared with SB3Policy
from scorbot_gym.policies.scripted import ScriptedGraspPolicy

BASE_KEY = "base_action"


class ResidualActionWrapper(gym.Wrapper):
    """Turn an env into the residual problem around a base policy on observations.

    Parameters
    ----------
    env
        A Dict-observation env (e.g. from :func:`scorbot_gym.make_env`) with a [-1, 1] Box
        action space.
    scale
        Largest change (in action units) the residual can make to each base action component.
    base
        The base policy; default ``ScriptedGraspPolicy.for_env(env)``.
    gripper
        Whether the residual also corrects the gripper command (the last action component).
        Off by default: the controller's gripper command is a timed open/close, and a
        continuous correction of it only narrows the approach opening or loosens the grip
        (the residual trained with it dropped 6 of 100 objects the controller holds, and 0
        with that correction zeroed).
    """

    def __init__(
        self, env: gym.Env, scale: float = 0.3, base: Policy | None = None, gripper: bool = False
    ) -> None:
        super().__init__(env)
        if not (np.isfinite(scale) and scale > 0):
            raise ValueError(f"residual scale must be a positive number, got {scale!r}")
        if not isinstance(env.observation_space, spaces.Dict):
            raise TypeError("ResidualActionWrapper needs a Dict observation space")
        if BASE_KEY in env.observation_space.spaces:
            raise ValueError(f"the observation already has an entry {BASE_KEY!r}")
        self.scale, self.gripper = float(scale), bool(gripper)
        self.base = base if base is not None else ScriptedGraspPolicy.for_env(env)
        shape = env.action_space.shape
        self.observation_space = spaces.Dict(
            {**env.observation_space.spaces, BASE_KEY: spaces.Box(-1.0, 1.0, shape, np.float32)}
        )
        if not self.gripper:  # the residual's own action: the arm's components
            self.action_space = spaces.Box(-1.0, 1.0, (shape[0] - 1,), np.float32)
        self._base_action = np.zeros(shape, np.float32)

    def _with_base(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        self._base_action = np.asarray(self.base.act(obs), np.float32)
        return {**obs, BASE_KEY: self._base_action.copy()}

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        seed_fn = getattr(self.base, "seed", None)
        if callable(seed_fn):
            seed_fn(seed)
        self.base.reset(obs, info)
        return self._with_base(obs), info

    def step(self, action: np.ndarray):
        applied = residual_action(self._base_action, action, self.scale)
        obs, reward, terminated, truncated, info = self.env.step(applied)
        info: dict[str, Any] = {**info, "applied_action": applied}
        return self._with_base(obs), reward, terminated, truncated, info
