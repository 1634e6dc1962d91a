"""Evaluation: seeded episodes and their summaries, and pose-estimator scoring."""

from scorbot_gym.evaluation.episodes import EpisodeResult, run_episode, run_episodes
from scorbot_gym.evaluation.summary import (
    format_summary,
    perception_summary,
    summarize,
    wilson_interval,
)

__all__ = [
    "EpisodeResult",
    "format_summary",
    "perception_summary",
    "run_episode",
    "run_episodes",
    "summarize",
    "wilson_interval",
]
