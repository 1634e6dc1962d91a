"""The policy protocol: every controller, scripted or learned, is a policy on observations.

A policy sees what the agent sees (the observation, and the ``info`` of ``reset`` for public
episode facts such as camera parameters) and nothing of the simulator. That is what lets the
same scripted controller run inside subprocess vector envs, behind any pose source, and be
compared with a learned policy on equal terms.
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class Policy(Protocol):
    """``reset(obs, info)`` at the start of every episode, then ``act(obs)`` once per step."""

    def reset(self, obs: dict[str, np.ndarray], info: dict[str, Any]) -> None: ...

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray: ...
