"""Pose sources: from one step's observation to the object's pose in the world frame.

The names below are imported on first access (PEP 562): the vision stack behind
``ModelSetPoseSource`` and the recognisers (scikit-learn, the pose estimators) costs an env
that runs on the oracle tens of MB of memory in every process, vector-env workers included.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

_WHERE = {
    "PerceptionFrame": "base",
    "PoseSource": "base",
    "WorldPose": "base",
    "ConstantPoseSource": "constant",
    "ModelSetPoseSource": "model_set",
    "NoisyOraclePoseSource": "oracle",
    "OraclePoseSource": "oracle",
    "make_recognizer": "recognizers",
    "FunctionPoseSource": "registry",
    "make_pose_source": "registry",
    "pose_source_names": "registry",
    "register_pose_source": "registry",
    "BackgroundSegmenter": "segmenters",
    "PrivilegedSegmenter": "segmenters",
    "Segmenter": "segmenters",
    "make_segmenter": "segmenters",
    "segmenter_names": "segmenters",
    "baseline_source_kwargs": "baseline_models",
}

__all__ = [
    "BackgroundSegmenter",
    "ConstantPoseSource",
    "FunctionPoseSource",
    "ModelSetPoseSource",
    "NoisyOraclePoseSource",
    "OraclePoseSource",
    "PerceptionFrame",
    "PoseSource",
    "PrivilegedSegmenter",
    "Segmenter",
    "WorldPose",
    "baseline_source_kwargs",
    "make_pose_source",
    "make_recognizer",
    "make_segmenter",
    "pose_source_names",
    "register_pose_source",
    "segmenter_names",
]

if TYPE_CHECKING:
    from scorbot_gym.perception.base import PerceptionFrame, PoseSource, WorldPose
    from scorbot_gym.perception.baseline_models import baseline_source_kwargs
    from scorbot_gym.perception.constant import ConstantPoseSource
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


def __getattr__(name: str) -> Any:
    if name not in _WHERE:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{_WHERE[name]}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_WHERE))
