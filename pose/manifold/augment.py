"""Training augmentation: half-plane-occluded copies of each training view.

Occluded test views lose part of their keypoints and silhouette; showing the regressor such
copies in ``fit`` teaches it what a partial view of each pose looks like.
"""

from __future__ import annotations

import cv2
import numpy as np

from pose.features.keypoints import Features


def occlude_features(
    f: Features, mask: np.ndarray, fraction: float, rng: np.random.Generator
) -> tuple[Features, np.ndarray]:
    """Hide ``fraction`` of ``mask`` behind a random half-plane (as
    :func:`scorbot_gym.data.views.occlude` does to test views) and keep the keypoints left
    visible. Returns those keypoints and the visible mask."""
    theta = rng.uniform(0, 2 * np.pi)
    d = np.array([np.cos(theta), np.sin(theta)])
    x, y, w, h = cv2.boundingRect(np.asarray(mask, np.uint8))
    ys, xs = np.nonzero(np.asarray(mask)[y : y + h, x : x + w])
    cut = np.quantile((xs + x) * d[0] + (ys + y) * d[1], 1.0 - fraction)
    visible = np.zeros(np.shape(mask), bool)
    keep = (xs + x) * d[0] + (ys + y) * d[1] <= cut
    visible[ys[keep] + y, xs[keep] + x] = True
    return f.subset(f.xy @ d <= cut), visible
