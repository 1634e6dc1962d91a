"""Evaluation: seeded episodes and their summaries, and pose-estimator scoring.

``RolloutConfig`` and ``run_rollout`` (a whole closed-loop run as one configuration, what
``scorbot-gym rollout`` and ``benchmarks/closed_loop.py`` run) are imported on first access
(PEP 562): they bring in the vision stack, which a caller that only summarises episodes should
not pay for.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from scorbot_gym.evaluation.episodes import EpisodeResult, run_episode, run_episodes
from scorbot_gym.evaluation.summary import (
    format_summary,
    perception_summary,
    summarize,
    wilson_interval,
)

_LAZY = {"RolloutConfig": "rollout", "run_rollout": "rollout", "run_rollouts": "rollout"}

__all__ = [
    "EpisodeResult",
    "RolloutConfig",
    "format_summary",
    "perception_summary",
    "run_episode",
    "run_episodes",
    "run_rollout",
    "run_rollouts",
    "summarize",
    "wilson_interval",
]

if TYPE_CHECKING:
    from scorbot_gym.evaluation.rollout import RolloutConfig, run_rollout, run_rollouts


def __getattr__(name: str) -> Any:
    if name not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
