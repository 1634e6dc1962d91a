"""A part-based appearance manifold, in the spirit of Mei et al. [28].

Mei et al. model an object's views as a high-dimensional manifold whose coordinates are the
appearances of its *parts*, so that a part hidden by an occluder removes only its own
coordinates instead of corrupting a global descriptor. Here the mask-cropped object
(:func:`pose.baselines._common.appearance_patch`) is cut into a ``grid x grid`` array of parts;
each part is described by a histogram of gradient orientations weighted by magnitude
(``n_bins`` bins, HOG-like) and by its visible fraction. The pose of a new view is that of the
training view nearest in the mean distance over the parts that are visible in *both* (at
least ``min_visible`` of the part's pixels inside the mask); a view with fewer than
``min_parts`` visible parts is invalid.

Simplifications against the paper: fixed grid parts instead of learned, deformable ones; the
manifold is the set of training views (nearest neighbour), with no statistical model of the
manifold's structure; no detection (the mask gives the object's box).
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np
from sklearn.utils.validation import check_is_fitted

from pose.baselines._common import (
    BaselineEstimator,
    appearance_input,
    check_training_set,
    invalid,
    object_region,
    require_masks,
)
from pose.features.keypoints import to_gray
from pose.geometry import centre_and_size
from pose.view import PoseEstimate, View


class PartBasedEstimator(BaselineEstimator):
    """Nearest training view in a grid-of-parts gradient-histogram space with visibility."""

    _FITTED = ("parts_", "visible_", *BaselineEstimator.TRANSLATION)

    def __init__(
        self,
        grid: int = 4,
        n_bins: int = 8,
        cell_size: int = 12,
        min_visible: float = 0.5,
        min_parts: int = 3,
    ):
        self.grid = grid
        self.n_bins = n_bins
        self.cell_size = cell_size
        self.min_visible = min_visible
        self.min_parts = min_parts

    def _describe(self, image: np.ndarray, region: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Part histograms ``(grid*grid, n_bins)`` (unit norm) and visible fractions."""
        side = self.grid * self.cell_size
        gray = to_gray(image).astype(np.float32)
        x, y, w, h = cv2.boundingRect(region.astype(np.uint8))
        half = max(w, h) / 2.0
        s = side / (2.0 * half)
        A = np.array(
            [[s, 0.0, side / 2.0 - s * (x + w / 2.0)], [0.0, s, side / 2.0 - s * (y + h / 2.0)]],
            np.float32,
        )
        if s < 1.0:
            gray = cv2.GaussianBlur(gray, (0, 0), 0.5 / s)
        g = cv2.warpAffine(gray, A, (side, side))
        m = cv2.warpAffine(region.astype(np.float32), A, (side, side)) > 0.5
        gx, gy = cv2.Sobel(g, cv2.CV_32F, 1, 0), cv2.Sobel(g, cv2.CV_32F, 0, 1)
        mag = np.hypot(gx, gy) * cv2.erode(m.astype(np.uint8), np.ones((3, 3), np.uint8))
        b = (np.floor((np.arctan2(gy, gx) + np.pi) / (2 * np.pi) * self.n_bins)).astype(int)
        b = np.clip(b, 0, self.n_bins - 1)
        c = self.cell_size
        cell = (np.arange(side) // c)[:, None] * self.grid + (np.arange(side) // c)[None, :]
        H = np.zeros((self.grid * self.grid, self.n_bins))
        np.add.at(H, (cell.ravel(), b.ravel()), mag.ravel())
        H /= np.maximum(np.linalg.norm(H, axis=1, keepdims=True), 1e-9)
        vis = np.bincount(cell.ravel(), m.ravel().astype(float), self.grid**2) / c**2
        return H.astype(np.float32), vis.astype(np.float32)

    def fit(self, views: Sequence[View], poses) -> PartBasedEstimator:
        if self.grid < 1 or self.n_bins < 2 or self.cell_size < 4:
            raise ValueError(
                f"need grid >= 1, n_bins >= 2, cell_size >= 4, got {self.grid}, {self.n_bins}, "
                f"{self.cell_size}"
            )
        if not 0.0 < self.min_visible <= 1.0:
            raise ValueError(f"min_visible must be in (0, 1], got {self.min_visible}")
        views, P = check_training_set(views, poses)
        require_masks(views, type(self).__name__)
        described = [self._describe(v.image, object_region(v)) for v in views]
        self.parts_ = np.array([d[0] for d in described])
        self.visible_ = np.array([d[1] for d in described])
        self._fit_translation(views, P)
        return self

    def _predict_one(self, view: View) -> PoseEstimate:
        check_is_fitted(self, "parts_")
        timer, region, failed = appearance_input(view)
        if failed is not None:
            return failed
        H, vis = self._describe(view.image, region)
        timer.lap("parts")
        both = (self.visible_ >= self.min_visible) & (vis >= self.min_visible)  # (N, parts)
        n_both = both.sum(axis=1)
        if n_both.max() < self.min_parts:
            return invalid(f"fewer than {self.min_parts} visible parts", timer)
        d = np.linalg.norm(self.parts_ - H[None], axis=2)  # (N, parts)
        mean_d = np.where(n_both >= self.min_parts, (d * both).sum(1) / np.maximum(n_both, 1), 9)
        nn = int(np.argmin(mean_d))
        timer.lap("match")
        centre, size = centre_and_size(region, np.zeros((1, 2)))
        t = self._translation(view.camera, centre, size, nn)
        R = self.tr_rotation_[nn].copy()
        return PoseEstimate(
            rotation=R,
            translation=t,
            confidence=float(max(0.0, 1.0 - mean_d[nn] / np.sqrt(2.0))),
            valid=True,
            timings_ms=timer.done(),
            rotation_coarse=R.copy(),
            translation_regressed=t,
        )
