"""A uniformly random policy: the floor every other policy is compared against."""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces


class RandomPolicy:
    """Samples the action space. ``seed(s)`` (called by the episode runner with the episode's
    seed) makes every episode reproducible on its own, whatever ran before it."""

    def __init__(self, action_space: spaces.Space, seed: int | None = None) -> None:
        self.action_space = action_space
        self.action_space.seed(seed)

    def seed(self, seed: int | None) -> None:
        self.action_space.seed(seed)

    def reset(self, obs: dict[str, np.ndarray], info: dict[str, Any]) -> None:
        pass

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        return np.asarray(self.action_space.sample())
