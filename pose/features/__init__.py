"""Local features: SIFT keypoints (stage a) and matching with RANSAC outlier removal (stage b)."""

from pose.features.keypoints import Features, SiftKeypoints, extract_sift, shared_keypoints
from pose.features.matching import DescriptorIndex, Match, RansacMatcher

__all__ = [
    "DescriptorIndex",
    "Features",
    "Match",
    "RansacMatcher",
    "SiftKeypoints",
    "extract_sift",
    "shared_keypoints",
]
