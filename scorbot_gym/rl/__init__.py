"""Learned grasping: SB3 training runs, a residual wrapper around the scripted controller,
scripted demonstrations and behaviour cloning, and training callbacks."""

from scorbot_gym.rl.residual import ResidualActionWrapper, residual_action
from scorbot_gym.rl.training import ALGOS, POSES, TrainConfig, resume, train

__all__ = [
    "ALGOS",
    "POSES",
    "ResidualActionWrapper",
    "TrainConfig",
    "residual_action",
    "resume",
    "train",
]
