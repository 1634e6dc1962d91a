"""Tasks: what the episode asks of the robot (placement, reward terms, success, failure causes)."""

from scorbot_gym.tasks.grasp import FAILURE_CAUSES, EpisodeState, GraspTask

__all__ = ["FAILURE_CAUSES", "EpisodeState", "GraspTask"]
