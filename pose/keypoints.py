"""Old import path of :mod:`pose.features.keypoints` (stage a), kept for existing code."""

from pose.features.keypoints import CROP_MARGIN, Features, SiftKeypoints, extract_sift, to_gray

__all__ = ["CROP_MARGIN", "Features", "SiftKeypoints", "extract_sift", "to_gray"]
