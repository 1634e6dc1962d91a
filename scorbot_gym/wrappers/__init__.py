"""Gymnasium wrappers: perception in the loop."""

from scorbot_gym.wrappers.pose_observation import MAX_AGE, PoseEstimateObservation

__all__ = ["MAX_AGE", "PoseEstimateObservation"]
