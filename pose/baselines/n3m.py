"""Natural 3D Markers (Hinterstoisser et al. [36]): a few distinctive, close 3-D points -> PnP.

N3M replaces an artificial marker by small groups of natural feature points chosen on the
object: points that are detected again in many views (repeatable) and whose 3-D positions are
known, grouped so that one group alone fixes the pose. Training here lifts the training views'
SIFT keypoints to 3-D (as :mod:`pose.baselines.pnp` does), merges the ones within
``merge_radius`` of each other into physical points, scores each point by the number of
training views it was detected in, keeps the best ``n_points``, and groups them greedily into
markers of ``points_per_marker`` nearest neighbours around the best remaining point. At test
time every marker with at least 4 matched points gives a pose (SQPnP on its own points); the
one that the most matches of *all* markers agree with (reprojection under
``reprojection_error``) wins and is refined on those inliers.

What it simplifies: SIFT and nearest-neighbour matching instead of the paper's randomised
trees; repeatability counted over the rendered training views instead of synthetic warps of
each patch; marker selection without the paper's check of each marker's pose accuracy; no
tracking between frames.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np
from scipy.spatial import cKDTree
from sklearn.utils.validation import check_is_fitted

from pose.baselines._common import BaselineEstimator, Timer, check_training_set, check_view, invalid
from pose.baselines.pnp import lifted_features, match_3d
from pose.features.keypoints import extract_sift
from pose.features.matching import DescriptorIndex
from pose.view import PoseEstimate, View


def _merge_points(xyz: np.ndarray, radius: float) -> np.ndarray:
    """Physical-point label of every lifted keypoint (leader clustering, densest first).

    Each keypoint's neighbours within ``radius`` are counted; in order of that count, a point
    not yet taken claims its untaken neighbours. Unlike connected components this never chains
    a whole textured region into one point.
    """
    tree = cKDTree(xyz)
    nbrs = tree.query_ball_point(xyz, radius)
    order = np.argsort(-np.array([len(n) for n in nbrs]), kind="stable")
    label = np.full(len(xyz), -1)
    k = 0
    for i in order:
        if label[i] >= 0:
            continue
        members = np.array(nbrs[i])
        label[members[label[members] < 0]] = k
        k += 1
    return label


class N3MEstimator(BaselineEstimator):
    """A few repeatable 3-D feature points, grouped into markers, each able to give a pose."""

    _FITTED = (
        "points_",
        "point_marker_",
        "descriptors_",
        "descriptor_point_",
        *BaselineEstimator.TRANSLATION,
    )

    def __init__(
        self,
        n_points: int = 60,
        points_per_marker: int = 6,
        max_train_features: int = 300,
        contrast_threshold: float = 0.03,
        merge_radius: float = 0.003,
        ratio: float = 0.8,
        reprojection_error: float = 3.0,
        min_inliers: int = 6,
        random_state: int = 0,
    ):
        self.n_points = n_points
        self.points_per_marker = points_per_marker
        self.max_train_features = max_train_features
        self.contrast_threshold = contrast_threshold
        self.merge_radius = merge_radius
        self.ratio = ratio
        self.reprojection_error = reprojection_error
        self.min_inliers = min_inliers
        self.random_state = random_state

    def fit(self, views: Sequence[View], poses) -> N3MEstimator:
        if self.points_per_marker < 4 or self.n_points < self.points_per_marker:
            raise ValueError(
                "need points_per_marker >= 4 and n_points >= points_per_marker, got "
                f"{self.points_per_marker}, {self.n_points}"
            )
        views, P = check_training_set(views, poses)
        xyz, desc, vid = lifted_features(views, P, self.max_train_features, self.contrast_threshold)
        label = _merge_points(xyz, self.merge_radius)
        # Repeatability: in how many distinct training views each physical point was found.
        seen = np.unique(np.c_[label, vid], axis=0)
        score = np.bincount(seen[:, 0], minlength=label.max() + 1)
        keep = np.argsort(-score, kind="stable")[: self.n_points]
        if (score[keep] >= 2).sum() >= self.points_per_marker:  # drop one-view points if we can
            keep = keep[score[keep] >= 2]
        centres = np.array([xyz[label == p].mean(axis=0) for p in keep])
        marker = np.full(len(keep), -1)
        free = np.ones(len(keep), bool)
        m = 0
        while free.sum() >= self.points_per_marker:  # greedy: best free point + its neighbours
            seed = np.nonzero(free)[0][0]
            cand = np.nonzero(free)[0]
            near = cand[np.argsort(np.linalg.norm(centres[cand] - centres[seed], axis=1))]
            marker[near[: self.points_per_marker]] = m
            free[near[: self.points_per_marker]] = False
            m += 1
        used = marker >= 0
        new_id = np.full(label.max() + 1, -1)
        new_id[keep[used]] = np.arange(used.sum())
        d_point = new_id[label]
        self.points_ = centres[used].astype(np.float32)
        self.point_marker_ = marker[used]
        self.descriptors_ = desc[d_point >= 0]
        self.descriptor_point_ = d_point[d_point >= 0]
        self._fit_translation(views, P)
        self._after_load()
        return self

    def _after_load(self) -> None:
        self.descriptors_ = self.descriptors_.astype(np.float32)
        self._index = DescriptorIndex(
            self.descriptors_, self.descriptor_point_, len(self.points_), self.random_state
        )

    def _predict_one(self, view: View) -> PoseEstimate:
        check_is_fitted(self, "points_")
        check_view(view)
        timer = Timer()
        mask = view.mask if view.mask is None else np.asarray(view.mask, bool)
        f = extract_sift(view.image, mask, 0, self.contrast_threshold)
        timer.lap("sift")
        if len(f) < 4:
            return invalid(f"only {len(f)} keypoints", timer, len(f))
        model = self.points_[self.descriptor_point_].astype(float)
        q, d = match_3d(self._index, f.descriptors, model, self.ratio, self.merge_radius)
        pt = self.descriptor_point_[d]
        obj, img = self.points_[pt].astype(float), f.xy[q].astype(float)
        timer.lap("match")
        K = np.asarray(view.camera.K, float)
        best = (0, None)
        for mk in np.unique(self.point_marker_[pt]) if len(pt) else ():
            sel = self.point_marker_[pt] == mk
            if len(np.unique(pt[sel])) < 4:
                continue
            ok, rvec, tvec = cv2.solvePnP(obj[sel], img[sel], K, None, flags=cv2.SOLVEPNP_SQPNP)
            if not ok or tvec[2, 0] <= 0:
                continue
            proj = cv2.projectPoints(obj, rvec, tvec, K, None)[0].reshape(-1, 2)
            inl = np.linalg.norm(proj - img, axis=1) < self.reprojection_error
            if inl.sum() > best[0]:
                best = (int(inl.sum()), (rvec, tvec, inl))
        if best[1] is None or best[0] < self.min_inliers:
            timer.lap("pnp")
            return invalid(f"no marker pose with {self.min_inliers} inliers", timer, len(f))
        rvec, tvec, inl = best[1]
        rvec, tvec = cv2.solvePnPRefineLM(obj[inl], img[inl], K, None, rvec, tvec)
        timer.lap("pnp")
        R, t = cv2.Rodrigues(rvec)[0], tvec.ravel()
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
