"""Pose sources: from one step's observation to the object's pose in the world frame."""

from scorbot_gym.perception.base import PerceptionFrame, PoseSource, WorldPose
from scorbot_gym.perception.model_set import ModelSetPoseSource
from scorbot_gym.perception.oracle import NoisyOraclePoseSource, OraclePoseSource
from scorbot_gym.perception.recognizers import make_recognizer
from scorbot_gym.perception.registry import (
    FunctionPoseSource,
    make_pose_source,
    pose_source_names,
    register_pose_source,
)
from scorbot_gym.perception.segmenters import (
    BackgroundSegmenter,
    PrivilegedSegmenter,
    Segmenter,
    make_segmenter,
    segmenter_names,
)

__all__ = [
    "BackgroundSegmenter",
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
    "make_recognizer",
    "make_segmenter",
    "pose_source_names",
    "register_pose_source",
    "segmenter_names",
]
