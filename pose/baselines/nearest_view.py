"""Nearest training view + homography: recognise the most similar training image, correct it.

A FLANN index over all training descriptors votes for the training views sharing the most
appearance with the new view; the ``n_candidates`` best-voted are matched exhaustively (ratio
test) and fitted a RANSAC homography; the one with the most inliers wins. Its known rotation,
turned about the optical axis by the homography's in-plane angle at the object centre
(:func:`pose.features.matching.local_similarity`), is the answer; the training view's mask centroid
carried through the homography gives the position (the shared silhouette method,
:class:`pose.baselines._common.BaselineEstimator`, with that view as reference).

This is the manifold estimator's refinement step on its own, without the manifold: under the
top camera with resting objects every test pose is a training pose turned in the image plane,
which is exactly what it recovers. What it simplifies: the correction is a rotation about the
optical axis only, so an out-of-plane difference to the nearest view (side camera, tilted
objects) stays as error.
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
    object_region,
)
from pose.features.keypoints import extract_sift
from pose.features.matching import (
    DescriptorIndex,
    apply_homography,
    local_similarity,
    ransac_homography,
    ratio_match,
)
from pose.geometry import centre_and_size
from pose.rotations import rot_z
from pose.view import PoseEstimate, View


class NearestViewEstimator(BaselineEstimator):
    """Best-matching training view (votes, then RANSAC homography inliers), in-plane corrected."""

    _FITTED = ("db_xy_", "db_desc_", "db_view_", *BaselineEstimator.TRANSLATION)

    def __init__(
        self,
        max_train_features: int = 200,
        contrast_threshold: float = 0.03,
        ratio: float = 0.85,
        ransac_threshold: float = 4.0,
        min_inliers: int = 8,
        n_candidates: int = 4,
        random_state: int = 0,
    ):
        self.max_train_features = max_train_features
        self.contrast_threshold = contrast_threshold
        self.ratio = ratio
        self.ransac_threshold = ransac_threshold
        self.min_inliers = min_inliers
        self.n_candidates = n_candidates
        self.random_state = random_state

    def fit(self, views: Sequence[View], poses) -> NearestViewEstimator:
        if self.min_inliers < 4 or self.n_candidates < 1:
            raise ValueError(
                f"need min_inliers >= 4 and n_candidates >= 1, got {self.min_inliers}, "
                f"{self.n_candidates}"
            )
        views, P = check_training_set(views, poses)
        xy, desc, vid = [], [], []
        for i, v in enumerate(views):
            f = extract_sift(
                v.image, object_region(v), self.max_train_features, self.contrast_threshold
            )
            xy.append(f.xy)
            desc.append(f.descriptors)
            vid.append(np.full(len(f), i))
        if sum(len(d) for d in desc) < self.min_inliers:
            raise ValueError("the training views have almost no SIFT keypoints: textureless?")
        self.db_xy_ = np.concatenate(xy).astype(np.float32)
        self.db_desc_ = np.concatenate(desc).astype(np.float32)
        self.db_view_ = np.concatenate(vid)
        self._fit_translation(views, P)
        self._after_load()
        return self

    def _after_load(self) -> None:
        self.db_desc_ = self.db_desc_.astype(np.float32)
        self.db_xy_ = self.db_xy_.astype(np.float32)
        n = len(self.tr_rotation_)
        self._index = DescriptorIndex(self.db_desc_, self.db_view_, n, self.random_state)
        self._start = np.searchsorted(self.db_view_, np.arange(n + 1))

    def _predict_one(self, view: View) -> PoseEstimate:
        check_is_fitted(self, "db_desc_")
        check_view(view)
        timer = Timer()
        mask = view.mask if view.mask is None else np.asarray(view.mask, bool)
        f = extract_sift(view.image, mask, 0, self.contrast_threshold)
        timer.lap("sift")
        if len(f) < self.min_inliers:
            return invalid(f"only {len(f)} keypoints", timer, len(f))
        votes = self._index.vote(f.descriptors)
        order = np.argsort(-votes, kind="stable")[: self.n_candidates]
        best = (0, -1, None)
        for v in order[votes[order] > 0]:
            a, b = self._start[v], self._start[v + 1]
            pairs = ratio_match(f.descriptors, self.db_desc_[a:b], self.ratio)
            if len(pairs) < self.min_inliers:
                continue
            H, inl = ransac_homography(
                self.db_xy_[a:b][pairs[:, 1]],
                f.xy[pairs[:, 0]],
                "ransac",
                self.ransac_threshold,
                self.random_state,
            )
            if H is not None and inl.sum() > best[0]:
                best = (int(inl.sum()), int(v), H)
        timer.lap("match")
        n_inl, v, H = best
        if H is None or n_inl < self.min_inliers:
            return invalid("no training view matches geometrically", timer, len(f))
        angle, scale = local_similarity(H, self.tr_centre_[v])
        centre = apply_homography(H, self.tr_centre_[v])[0]
        size = self.tr_size_[v] * scale
        if not (0.5 < scale < 2.0 and np.isfinite(centre).all()):  # degenerate homography
            centre, size = centre_and_size(object_region(view), f.xy)
        R = rot_z(angle) @ self.tr_rotation_[v]
        t = self._translation(view.camera, centre, size, v)
        timer.lap("refine")
        return PoseEstimate(
            rotation=R,
            translation=t,
            confidence=float(n_inl / len(f)),
            valid=True,
            timings_ms=timer.done(),
            rotation_coarse=self.tr_rotation_[v].copy(),
            translation_regressed=t,
            n_keypoints=len(f),
            n_inliers=n_inl,
        )
