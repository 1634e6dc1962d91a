"""Old import path of :mod:`pose.features.matching` (stage b), kept for existing code."""

from pose.features.matching import (
    DescriptorIndex,
    RansacMatcher,
    apply_homography,
    local_similarity,
    ransac_homography,
    ratio_match,
)

__all__ = [
    "DescriptorIndex",
    "RansacMatcher",
    "apply_homography",
    "local_similarity",
    "ransac_homography",
    "ratio_match",
]
