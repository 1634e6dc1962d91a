"""Pose sources: from one step's observation to the object's pose in the world frame."""

from scorbot_gym.perception.base import PerceptionFrame, PoseSource, WorldPose
from scorbot_gym.perception.model_set import ModelSetPoseSource
from scorbot_gym.perception.oracle import NoisyOraclePoseSource, OraclePoseSource
from scorbot_gym.perception.registry import (
    FunctionPoseSource,
    make_pose_source,
    pose_source_names,
    register_pose_source,
)
from scorbot_gym.perception.segmenters import PrivilegedSegmenter, Segmenter

__all__ = [
    "FunctionPoseSource",
    "ModelSetPoseSource",
    "NoisyOraclePoseSource",
    "OraclePoseSource",
    "PerceptionFrame",
    "PoseSource",
    "PrivilegedSegmenter",
    "Segmenter",
    "WorldPose",
    "make_pose_source",
    "pose_source_names",
    "register_pose_source",
]
