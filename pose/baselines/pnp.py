"""SIFT + PnP RANSAC against 3-D model points: what a practitioner would build first.

Training lifts every SIFT keypoint of every training view to the object frame with the
view's depth and pose (:func:`pose.baselines._common.lift_to_object`), giving a cloud of 3-D
model points each with a descriptor (a point seen in several views appears several times). A
new view's keypoints are matched to that cloud with Lowe's ratio test — the second neighbour
taken from a *different* 3-D place (over ``merge_radius`` away), since the nearest several
descriptors are often the same point seen from neighbouring views — and the pose is solved by
RANSAC PnP (EPnP hypotheses, Levenberg-Marquardt refinement on the inliers).

What it simplifies: no CAD model or texture atlas (the 3-D points come from the rendered
training depth, which a practitioner gets from an RGB-D scan); no bundle adjustment of the
points; nothing at all from the silhouette. A view with fewer than ``min_inliers`` PnP inliers
is invalid.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from sklearn.utils.validation import check_is_fitted

from pose.baselines._common import (
    BaselineEstimator,
    Timer,
    check_training_set,
    check_view,
    invalid,
    lift_to_object,
    object_region,
    pnp,
)
from pose.features.keypoints import extract_sift
from pose.features.matching import DescriptorIndex, ratio_test_3d
from pose.view import PoseEstimate, View


def lifted_features(
    views: Sequence[View],
    poses: np.ndarray,
    n_features: int,
    contrast_threshold: float,
    upscale: float = 1.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Object-frame points ``(M, 3)``, unit descriptors ``(M, 128)`` and view indices ``(M,)``
    of the training views' SIFT keypoints that have a depth."""
    xyz, desc, vid = [], [], []
    for i, (view, pose) in enumerate(zip(views, poses, strict=True)):
        region = object_region(view)
        f = extract_sift(view.image, region, n_features, contrast_threshold, upscale=upscale)
        if len(f) == 0:
            continue
        pts, ok = lift_to_object(view, f.xy.astype(float), pose)
        xyz.append(pts)
        desc.append(f.descriptors[ok])
        vid.append(np.full(len(pts), i))
    if not xyz or sum(len(p) for p in xyz) < 6:
        raise ValueError(
            "fewer than 6 training keypoints with a depth: check that the views show a textured "
            "object and carry View.depth (render_views(..., depth=True))"
        )
    return np.concatenate(xyz), np.concatenate(desc).astype(np.float32), np.concatenate(vid)


def match_3d(
    index: DescriptorIndex,
    query: np.ndarray,
    points: np.ndarray,
    ratio: float,
    merge_radius: float,
    k: int = 8,
) -> tuple[np.ndarray, np.ndarray]:
    """Query indices and model-point indices of the matches passing the 3-D-aware ratio test
    (:func:`pose.features.matching.ratio_test_3d`) among each query's ``k`` nearest descriptors."""
    idx, dist = index.nearest(query, k)
    return ratio_test_3d(idx, dist, points, ratio, merge_radius)


class SiftPnPEstimator(BaselineEstimator):
    """SIFT matches to depth-lifted training keypoints, then RANSAC PnP."""

    _FITTED = ("points_", "descriptors_", "point_view_", *BaselineEstimator.TRANSLATION)

    def __init__(
        self,
        max_train_features: int = 300,
        contrast_threshold: float = 0.03,
        ratio: float = 0.8,
        merge_radius: float = 0.004,
        reprojection_error: float = 3.0,
        min_inliers: int = 8,
        random_state: int = 0,
        upscale: float = 1.0,
    ):
        self.max_train_features = max_train_features
        self.contrast_threshold = contrast_threshold
        self.ratio = ratio
        self.merge_radius = merge_radius
        self.reprojection_error = reprojection_error
        self.min_inliers = min_inliers
        self.random_state = random_state
        self.upscale = upscale

    def fit(self, views: Sequence[View], poses) -> SiftPnPEstimator:
        if self.min_inliers < 6 or not 0.0 < self.ratio <= 1.0:
            raise ValueError(
                f"need min_inliers >= 6 and ratio in (0, 1], got {self.min_inliers}, {self.ratio}"
            )
        views, P = check_training_set(views, poses)
        self.points_, self.descriptors_, self.point_view_ = lifted_features(
            views, P, self.max_train_features, self.contrast_threshold, self.upscale
        )
        self.points_ = self.points_.astype(np.float32)
        self._fit_translation(views, P)
        self._after_load()
        return self

    def _after_load(self) -> None:
        self.descriptors_ = self.descriptors_.astype(np.float32)
        self._index = DescriptorIndex(
            self.descriptors_, self.point_view_, len(self.tr_rotation_), self.random_state
        )

    def _predict_one(self, view: View) -> PoseEstimate:
        check_is_fitted(self, "points_")
        check_view(view)
        timer = Timer()
        mask = view.mask if view.mask is None else np.asarray(view.mask, bool)
        f = extract_sift(view.image, mask, 0, self.contrast_threshold, upscale=self.upscale)
        timer.lap("sift")
        if len(f) < self.min_inliers:
            return invalid(f"only {len(f)} keypoints", timer, len(f))
        q, m = match_3d(
            self._index, f.descriptors, self.points_.astype(float), self.ratio, self.merge_radius
        )
        timer.lap("match")
        R, t, inl = pnp(
            self.points_[m], f.xy[q], view.camera, self.reprojection_error, self.random_state
        )
        timer.lap("pnp")
        if R is None or inl.sum() < self.min_inliers:
            return invalid(f"no PnP pose with {self.min_inliers} inliers", timer, len(f))
        return PoseEstimate(
            rotation=R,
            translation=t,
            confidence=float(inl.sum() / len(f)),
            valid=True,
            timings_ms=timer.done(),
            rotation_coarse=R.copy(),
            translation_regressed=t.copy(),
            n_keypoints=len(f),
            n_inliers=int(inl.sum()),
        )
