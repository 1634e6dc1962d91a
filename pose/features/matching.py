"""Stage b: descriptor matching and RANSAC outlier removal.

A query is matched in two steps. A FLANN index over all training descriptors votes for the
training views that share the most appearance with the query; each of the few best-voted views
is then matched exhaustively (mutual ratio test) and a homography is fitted by RANSAC. The
inliers are the keypoints kept for the manifold; the best homography also serves refinement.
:class:`RansacMatcher` is the stage object holding these choices.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import cv2
import numpy as np
from sklearn.base import BaseEstimator

_METHODS = {"ransac": cv2.RANSAC, "magsac": cv2.USAC_MAGSAC}


def ratio_match(query: np.ndarray, train: np.ndarray, ratio: float = 0.8) -> np.ndarray:
    """Index pairs ``(M, 2)`` (query, train) passing Lowe's ratio test (unit descriptors)."""
    if len(query) == 0 or len(train) < 2:
        return np.zeros((0, 2), dtype=np.int64)
    # Squared distance between unit vectors is 2 - 2 cos; the largest dot products are nearest.
    # Two arg-max passes find the two nearest (a partial sort costs more): where the two
    # largest tie, the test fails whichever is called first, so ties cannot change the result.
    sim = query @ train.T
    rows = np.arange(len(query))
    best = sim.argmax(axis=1)
    s1 = sim[rows, best]
    sim[rows, best] = -np.inf
    s2 = sim.max(axis=1)
    d1 = np.sqrt(np.maximum(2 - 2 * s1, 0))
    d2 = np.sqrt(np.maximum(2 - 2 * s2, 0))
    ok = d1 < ratio * d2
    q = np.nonzero(ok)[0]
    return np.c_[q, best[ok]]


def ransac_homography(
    src: np.ndarray,
    dst: np.ndarray,
    method: str = "ransac",
    threshold: float = 4.0,
    seed: int = 0,
    max_iters: int = 2000,
) -> tuple[np.ndarray | None, np.ndarray]:
    """Homography ``dst ~ H src`` by robust fitting and the boolean inlier mask.

    Returns ``(None, all-False)`` when fewer than 4 correspondences or no model is found.
    ``seed`` seeds OpenCV's RNG so that the same input always gives the same inliers.
    """
    if method not in _METHODS:
        raise ValueError(f"unknown robust method {method!r}; valid: {sorted(_METHODS)}")
    src = np.asarray(src, np.float32).reshape(-1, 2)
    dst = np.asarray(dst, np.float32).reshape(-1, 2)
    none = np.zeros(len(src), dtype=bool)
    if len(src) < 4:
        return None, none
    cv2.setRNGSeed(int(seed))
    H, inl = cv2.findHomography(
        src, dst, _METHODS[method], threshold, maxIters=max_iters, confidence=0.995
    )
    if H is None or inl is None:
        return None, none
    return H, inl.ravel().astype(bool)


def local_similarity(H: np.ndarray, point: np.ndarray) -> tuple[float, float]:
    """In-plane rotation (radians, image axes) and scale of ``H`` linearised at ``point``.

    The Jacobian of the homography at the point is reduced to its closest similarity
    ``s [[cos, -sin], [sin, cos]]``.
    """
    x, y = float(point[0]), float(point[1])
    w = H[2, 0] * x + H[2, 1] * y + H[2, 2]
    u = (H[0, 0] * x + H[0, 1] * y + H[0, 2]) / w
    v = (H[1, 0] * x + H[1, 1] * y + H[1, 2]) / w
    J = np.array(
        [
            [(H[0, 0] - u * H[2, 0]) / w, (H[0, 1] - u * H[2, 1]) / w],
            [(H[1, 0] - v * H[2, 0]) / w, (H[1, 1] - v * H[2, 1]) / w],
        ]
    )
    a = 0.5 * (J[0, 0] + J[1, 1])
    b = 0.5 * (J[1, 0] - J[0, 1])
    return float(np.arctan2(b, a)), float(np.hypot(a, b))


def apply_homography(H: np.ndarray, pts: np.ndarray) -> np.ndarray:
    p = np.atleast_2d(np.asarray(pts, float))
    q = np.c_[p, np.ones(len(p))] @ H.T
    return q[:, :2] / q[:, 2:3]


def ratio_test_3d(
    idx: np.ndarray, dist: np.ndarray, points: np.ndarray, ratio: float, merge_radius: float
) -> tuple[np.ndarray, np.ndarray]:
    """Query indices and index rows of the matches passing a 3-D-aware ratio test.

    ``idx``, ``dist``: each query descriptor's nearest index rows, nearest first
    (:meth:`DescriptorIndex.nearest`); ``points``: every row's object-frame point (NaN where
    unknown). The second neighbour of the ratio test is the nearest one from a *different*
    3-D place (over ``merge_radius`` away): the nearest several descriptors are often the same
    point seen from neighbouring training views, and comparing with those would reject it.
    A query whose nearest row has no 3-D point is skipped."""
    valid = idx >= 0  # FLANN's misses (-1) come last in each row
    rows = np.where(valid, idx, 0)
    nearest = points[rows[:, 0]]
    known = valid[:, 0] & np.isfinite(nearest).all(axis=1)
    # An unknown point is never "the same place": it can only make the test stricter.
    far = valid & ~(np.linalg.norm(points[rows] - nearest[:, None, :], axis=2) <= merge_radius)
    second = dist[np.arange(len(idx)), far.argmax(axis=1)]  # the first far neighbour's
    ok = known & (~far.any(axis=1) | (dist[:, 0] < ratio * second))
    q = np.nonzero(ok)[0]
    return q.astype(int), idx[q, 0].astype(int)


@dataclass
class DescriptorIndex:
    """Approximate nearest-neighbour index over the descriptors of all training views."""

    descriptors: np.ndarray
    view_ids: np.ndarray
    n_views: int
    seed: int = 0

    def __post_init__(self) -> None:
        cv2.setRNGSeed(int(self.seed))  # FLANN's randomised kd-trees draw from OpenCV's RNG
        self._flann = cv2.FlannBasedMatcher(dict(algorithm=1, trees=4), dict(checks=32))
        self._flann.add([np.ascontiguousarray(self.descriptors, np.float32)])
        self._flann.train()

    def nearest(self, query: np.ndarray, k: int = 5) -> tuple[np.ndarray, np.ndarray]:
        """Indices and distances ``(M, k)`` of the ``k`` nearest training descriptors of each
        query descriptor, nearest first (index -1, distance inf where FLANN found fewer)."""
        k = max(1, min(k, len(self.descriptors)))
        idx = np.full((len(query), k), -1, np.int64)
        dist = np.full((len(query), k), np.inf)
        if len(query) == 0:
            return idx, dist
        for i, ms in enumerate(self._flann.knnMatch(np.ascontiguousarray(query, np.float32), k=k)):
            for j, m in enumerate(ms):
                idx[i, j], dist[i, j] = m.trainIdx, m.distance
        return idx, dist

    def vote(
        self,
        query: np.ndarray,
        k: int = 5,
        max_dist: float = 0.6,
        neighbours: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> np.ndarray:
        """Votes ``(n_views,)``: each query descriptor votes once for every view among its ``k``
        nearest training descriptors closer than ``max_dist`` (``neighbours``: the output of
        :meth:`nearest`, when already computed)."""
        votes = np.zeros(self.n_views)
        if len(query) == 0:
            return votes
        idx, dist = neighbours if neighbours is not None else self.nearest(query, k)
        close = (dist[:, :k] < max_dist) & (idx[:, :k] >= 0)
        for row, ok in zip(idx[:, :k], close, strict=True):
            for v in set(self.view_ids[row[ok]].tolist()):
                votes[v] += 1
        return votes


class Match(NamedTuple):
    """One training view consistent with the query: its index, the homography mapping its
    keypoints onto the query's, the query keypoints that are inliers of it, and the rows of the
    index's descriptors they matched (``db_rows[i]`` for ``inliers[i]``)."""

    view: int
    H: np.ndarray
    inliers: np.ndarray
    db_rows: np.ndarray
    pairs: np.ndarray  # (P, 2): every ratio-test pair (query keypoint, index row), inliers or not


class RansacMatcher(BaseEstimator):
    """Outlier-removal stage: vote with a FLANN index, then a RANSAC homography per candidate.

    The ``n_candidates`` training views with most votes are each matched exhaustively (ratio
    test at ``ratio``) and fitted with a ``method`` homography (``"ransac"`` or ``"magsac"``,
    reprojection ``threshold`` in pixels); a view counts when at least ``min_inliers`` agree.
    Voting first keeps the exhaustive matching to a few views whatever the database size.
    """

    def __init__(
        self,
        ratio: float = 0.85,
        method: str = "ransac",
        threshold: float = 4.0,
        min_inliers: int = 8,
        n_candidates: int = 4,
    ):
        self.ratio = ratio
        self.method = method
        self.threshold = threshold
        self.min_inliers = min_inliers
        self.n_candidates = n_candidates

    def validate(self) -> None:
        if self.min_inliers < 4:
            raise ValueError(f"min_inliers must be >= 4 (a homography), got {self.min_inliers}")
        if self.n_candidates < 1:
            raise ValueError(f"n_candidates must be >= 1, got {self.n_candidates}")
        if self.method not in _METHODS:
            raise ValueError(f"method must be one of {sorted(_METHODS)}, got {self.method!r}")
        if not 0 < self.ratio <= 1:
            raise ValueError(f"ratio must be in (0, 1], got {self.ratio}")

    def build_index(
        self, descriptors: np.ndarray, view_ids: np.ndarray, n_views: int, seed: int = 0
    ) -> DescriptorIndex:
        return DescriptorIndex(descriptors, view_ids, n_views, seed)

    def match(
        self,
        descriptors: np.ndarray,
        xy: np.ndarray,
        index: DescriptorIndex,
        neighbours: tuple[np.ndarray, np.ndarray],
        db_xy: np.ndarray,
        view_start: np.ndarray,
        seed: int = 0,
    ) -> list[Match]:
        """The best-voted training views that a homography explains, in vote order.
        ``view_start[v]:view_start[v + 1]`` are view ``v``'s rows of the index's descriptors."""
        votes = index.vote(descriptors, neighbours=neighbours)
        order = np.argsort(-votes, kind="stable")[: self.n_candidates]
        results = []
        for v in order[votes[order] > 0]:
            a, b = view_start[v], view_start[v + 1]
            pairs = ratio_match(descriptors, index.descriptors[a:b], self.ratio)
            if len(pairs) < self.min_inliers:
                continue
            H, inl = ransac_homography(
                db_xy[a:b][pairs[:, 1]], xy[pairs[:, 0]], self.method, self.threshold, seed
            )
            if H is not None and inl.sum() >= self.min_inliers:
                results.append(
                    Match(int(v), H, pairs[inl, 0], a + pairs[inl, 1], pairs + np.array([0, a]))
                )
        return results
