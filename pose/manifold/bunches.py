"""Stage c: group keypoints into bunches by k-means on their image locations (eq. 1).

k-means minimises ``sum_j sum_{x in C_j} ||x - mu_j||^2`` over the keypoint locations. Each
bunch becomes one vector that joins appearance (the re-normalised mean unit descriptor of its
members) and geometry (its centroid relative to the object centre and its spread, both divided
by the object size, so the vector does not change when the object moves or changes scale).
:class:`KMeansBunches` is the stage object holding these choices.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from sklearn.base import BaseEstimator


@dataclass(frozen=True)
class Bunches:
    """``vectors`` ``(k, 131)`` = [w_a * mean descriptor (128), w_g * offset (2), w_g * spread]."""

    vectors: np.ndarray
    offsets: np.ndarray  # (k, 2) centroid - object centre, in object sizes (image axes)
    counts: np.ndarray  # (k,) members per bunch
    labels: np.ndarray  # (N,) bunch of each keypoint


def kmeans_locations(xy: np.ndarray, n_bunches: int, seed: int = 0, attempts: int = 3):
    """Labels ``(N,)`` and centres ``(k, 2)`` of a seeded k-means++ clustering of ``xy``."""
    xy = np.asarray(xy, np.float32).reshape(-1, 2)
    if n_bunches < 1:
        raise ValueError(f"n_bunches must be >= 1, got {n_bunches}")
    if len(xy) < n_bunches:
        raise ValueError(f"need at least n_bunches={n_bunches} keypoints, got {len(xy)}")
    cv2.setRNGSeed(int(seed))
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)
    _, labels, centres = cv2.kmeans(xy, n_bunches, None, crit, attempts, cv2.KMEANS_PP_CENTERS)
    return labels.ravel().astype(np.int64), centres.astype(np.float64)


def make_bunches(
    xy: np.ndarray,
    descriptors: np.ndarray,
    centre: np.ndarray,
    size: float,
    n_bunches: int,
    appearance_weight: float = 1.0,
    geometry_weight: float = 1.0,
    seed: int = 0,
) -> Bunches:
    """Cluster keypoints into ``n_bunches`` bunches and build one vector per bunch."""
    if size <= 0:
        raise ValueError(f"object size must be positive, got {size}")
    labels, _ = kmeans_locations(xy, n_bunches, seed)
    xy = np.asarray(xy, float)
    vecs, offs, counts = [], [], []
    for j in range(n_bunches):
        member = labels == j
        n = int(member.sum())
        if n == 0:  # k-means can leave a cluster empty on duplicate points
            d, c, s = np.zeros(128), np.asarray(centre, float), 0.0
        else:
            d = descriptors[member].mean(axis=0)
            d = d / max(np.linalg.norm(d), 1e-12)
            c = xy[member].mean(axis=0)
            s = float(np.sqrt(((xy[member] - c) ** 2).sum(axis=1).mean()))
        off = (c - centre) / size
        vecs.append(np.r_[appearance_weight * d, geometry_weight * off, geometry_weight * s / size])
        offs.append(off)
        counts.append(n)
    return Bunches(np.array(vecs), np.array(offs), np.array(counts), labels)


class KMeansBunches(BaseEstimator):
    """Bunch stage: ``n_bunches`` k-means bunches; ``appearance_weight`` and
    ``geometry_weight`` scale the descriptor and the geometric parts of each bunch vector, i.e.
    how much the distances between bunches reflect texture versus layout."""

    def __init__(
        self, n_bunches: int = 8, appearance_weight: float = 1.0, geometry_weight: float = 2.0
    ):
        self.n_bunches = n_bunches
        self.appearance_weight = appearance_weight
        self.geometry_weight = geometry_weight

    def validate(self) -> None:
        if self.n_bunches < 2:
            raise ValueError(f"n_bunches must be >= 2, got {self.n_bunches}")

    def build(
        self, xy: np.ndarray, descriptors: np.ndarray, centre: np.ndarray, size: float, seed: int
    ) -> Bunches:
        return make_bunches(
            xy,
            descriptors,
            centre,
            size,
            self.n_bunches,
            self.appearance_weight,
            self.geometry_weight,
            seed=seed,
        )
