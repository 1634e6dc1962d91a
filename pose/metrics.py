"""Pose error measures, with the BOP toolkit's definitions.

Rotations ``(3, 3)`` map object to camera coordinates; translations are in metres unless stated.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from pose.rotations import geodesic_deg
from pose.symmetry import Symmetry

if TYPE_CHECKING:
    from pose.view import View


def rotation_error_deg(
    R_est: np.ndarray, R_gt: np.ndarray, symmetry: Symmetry | None = None, step_deg: float = 1.0
) -> float:
    """Geodesic angle ``arccos((tr(R_est R_gt^T) - 1) / 2)`` in degrees.

    With a ``symmetry``, the minimum over the ground truth's symmetric equivalents
    ``R_gt S`` (axial symmetries sampled every ``step_deg``).
    """
    R_est, R_gt = np.asarray(R_est, float), np.asarray(R_gt, float)
    if R_est.shape != (3, 3) or R_gt.shape != (3, 3):
        raise ValueError(f"rotations must be 3x3, got {R_est.shape} and {R_gt.shape}")
    if not (np.isfinite(R_est).all() and np.isfinite(R_gt).all()):
        return float("nan")
    if symmetry is None:
        return float(geodesic_deg(R_est, R_gt))
    # tr(R_est (R_gt S)^T) = <R_gt^T R_est, S> for every S at once; the smallest angle is the
    # largest trace (arccos falls), so one arccos, not one per symmetry (an axial set is 360).
    trace = float((symmetry.rotations(step_deg).reshape(-1, 9) @ (R_gt.T @ R_est).ravel()).max())
    return math.degrees(math.acos(min(max((trace - 1.0) / 2.0, -1.0), 1.0)))  # one number


def translation_error(t_est: np.ndarray, t_gt: np.ndarray) -> float:
    """Euclidean distance between the translations (same unit as the inputs)."""
    return float(np.linalg.norm(np.asarray(t_est, float).ravel() - np.asarray(t_gt, float).ravel()))


def _transform(R, t, pts):
    return np.asarray(pts, float) @ np.asarray(R, float).T + np.asarray(t, float).ravel()


def add(R_est, t_est, R_gt, t_gt, points: np.ndarray) -> float:
    """ADD: mean distance between model points under the two poses."""
    e = _transform(R_est, t_est, points) - _transform(R_gt, t_gt, points)
    return float(np.linalg.norm(e, axis=1).mean())


def add_s(R_est, t_est, R_gt, t_gt, points: np.ndarray, tree=None) -> float:
    """ADD-S (BOP's ``adi``): mean distance from each ground-truth-posed point to the nearest
    estimate-posed point; indifferent to symmetries.

    Cheap enough to score every env step: a point's own counterpart bounds its nearest
    neighbour, so only the points that moved are searched, and only within that bound; the
    search runs in the estimate's object frame (a rotation keeps distances), where ``tree``, a
    ``scipy.spatial.cKDTree`` of ``points``, can be built once per model (one is built here
    when not given). ``R_est`` must be a rotation.
    """
    points = np.asarray(points, float)
    R_est, R_gt = np.asarray(R_est, float), np.asarray(R_gt, float)
    t_est, t_gt = np.asarray(t_est, float).ravel(), np.asarray(t_gt, float).ravel()
    # each point's distance to its own counterpart: (R_gt - R_est) p + (t_gt - t_est)
    gap = points @ (R_gt - R_est).T + (t_gt - t_est)
    nearest = np.sqrt(np.einsum("ij,ij->i", gap, gap))  # row norms; np.linalg.norm's are slow
    moved = nearest > 0.0
    if moved.any():
        if tree is None:
            from scipy.spatial import cKDTree  # here: scipy costs an oracle-only env ~20 MB

            tree = cKDTree(points)
        local = (_transform(R_gt, t_gt, points[moved]) - t_est) @ R_est
        bound = nearest[moved]
        found = tree.query(local, k=1, distance_upper_bound=float(bound.max()) * (1 + 1e-9))[0]
        nearest[moved] = np.minimum(bound, found)  # inf where nothing is nearer than the bound
    return float(nearest.mean())


def success_rate(rot_err_deg, thr_deg: float = 5.0) -> float:
    """Fraction of views with rotation error below ``thr_deg`` (NaN = invalid = failure)."""
    e = np.asarray(rot_err_deg, float)
    return float(np.mean(np.nan_to_num(e, nan=np.inf) < thr_deg)) if e.size else float("nan")


def success_rate_deg_cm(rot_err_deg, trans_err_m, thr_deg: float = 5.0, thr_m: float = 0.05):
    """The 5 deg / 5 cm criterion: both errors below their thresholds."""
    r = np.nan_to_num(np.asarray(rot_err_deg, float), nan=np.inf)
    t = np.nan_to_num(np.asarray(trans_err_m, float), nan=np.inf)
    return float(np.mean((r < thr_deg) & (t < thr_m))) if r.size else float("nan")


def summarize(rot_err_deg, trans_err_m, coarse_err_deg=None, trans_reg_err_m=None) -> dict:
    """The figures the CLI and the benchmark report for one set of views."""
    r = np.asarray(rot_err_deg, float)
    t = np.asarray(trans_err_m, float)
    out = {
        "n_views": int(r.size),
        "valid_rate": float(np.mean(np.isfinite(r))) if r.size else float("nan"),
        "success_5deg": success_rate(r),
        "success_5deg_5cm": success_rate_deg_cm(r, t),
        "median_rot_err_deg": float(np.nanmedian(r)) if np.isfinite(r).any() else float("nan"),
        "mean_rot_err_deg": float(np.nanmean(r)) if np.isfinite(r).any() else float("nan"),
        "median_trans_err_cm": float(np.nanmedian(t) * 100) if np.isfinite(t).any() else None,
    }
    if coarse_err_deg is not None:
        c = np.asarray(coarse_err_deg, float)
        out["coarse_success_5deg"] = success_rate(c)
        out["coarse_median_rot_err_deg"] = float(np.nanmedian(c)) if np.isfinite(c).any() else None
    if trans_reg_err_m is not None:
        tr = np.asarray(trans_reg_err_m, float)
        out["regressed_median_trans_err_cm"] = (
            float(np.nanmedian(tr) * 100) if np.isfinite(tr).any() else None
        )
    return out


class ScoredEstimator:
    """``score``, the one way every pose estimator rates a set of views: the mixin for any
    class whose ``predict`` takes a sequence of views (scikit-learn's ``score`` convention,
    so ``GridSearchCV`` and ``cross_val_score`` can rate it)."""

    def score(self, views: Sequence[View], poses, symmetry: Symmetry | None = None) -> float:
        """Share of ``views`` whose rotation is within 5 degrees of ``poses`` (``(N, 4, 4)``
        ``camera_from_object``), invalid answers counting as failures; with ``symmetry`` the
        error is to the nearest symmetric equivalent (:func:`rotation_error_deg`)."""
        views = list(views)
        P = np.asarray(poses, float)
        if P.shape != (len(views), 4, 4):
            raise ValueError(
                f"poses must be ({len(views)}, 4, 4) camera_from_object matrices, got {P.shape}"
            )
        if not views:
            raise ValueError("score needs at least one view")
        errs = [
            rotation_error_deg(e.rotation, p[:3, :3], symmetry) if e.valid else np.nan
            for e, p in zip(self.predict(views), P, strict=True)
        ]
        return success_rate(errs, 5.0)
