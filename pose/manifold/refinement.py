"""Optional last stage: refine the coarse rotation from the matched training views.

:class:`HomographyRefiner` (the default): the homography to the best-matching training view,
linearised at the object centre, gives the in-plane angle between the two views; that training
view's known rotation turned by this angle about the optical axis replaces the manifold's
answer. It helps most at high occlusion on box-like objects, where few bunches are left to
describe the aspect, but it can only answer rotations that some training view shows turned
about the optical axis.

:class:`PnPRefiner`: a 3-D answer. Training lifts every keypoint of the match database to the
object frame with the view's depth; at prediction the ratio-test pairs of the matched training
views give 2-D-3-D correspondences, and RANSAC PnP solves the full pose from them. An object
leaning out of its resting pose, which no training view shows, is answered by geometry instead
of by the nearest view; the homography answer is kept when PnP finds too few inliers or does not
explain the correspondences clearly better.

``refiner=None`` in the estimator keeps the pure manifold answer (``PoseEstimate.rotation_coarse``
always holds it).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from sklearn.base import BaseEstimator

from pose.camera import CameraModel
from pose.features.matching import ratio_test_3d
from pose.geometry import pnp
from pose.rotations import geodesic_deg, rot_z

_CORRESPONDENCES = ("ratio", "homography", "ratio+global")


@dataclass(frozen=True)
class RefinementInput:
    """What the estimator knows when it refines: the coarse rotation, the best view's
    homography angle and rotation, and the matched keypoints (query pixels ``xy`` with the
    database rows they matched, ``db_rows``: the first ``n_inliers`` are homography inliers,
    the rest other ratio-test pairs of the matched views; ``db_xyz`` holds the object-frame
    point of every database row, NaN where training had no depth, or is None;
    ``keypoints_xy`` every query keypoint's pixel and ``neighbours`` its nearest database rows
    and descriptor distances, nearest first, for a refiner that matches against the whole
    database)."""

    R_coarse: np.ndarray
    R_ray: np.ndarray
    angle: float
    R_view: np.ndarray
    xy: np.ndarray
    db_rows: np.ndarray
    db_xyz: np.ndarray | None
    camera: CameraModel
    seed: int = 0
    n_inliers: int | None = None
    keypoints_xy: np.ndarray | None = None
    neighbours: tuple[np.ndarray, np.ndarray] | None = None


class HomographyRefiner(BaseEstimator):
    """Rotation of the best-matching training view, turned by the homography's in-plane angle.

    ``R_ray`` maps the (allocentric) training rotation back to the camera frame (the identity
    for egocentric models)."""

    needs_depth = False

    def validate(self) -> None:
        return None

    def refine(self, inp: RefinementInput) -> tuple[np.ndarray, np.ndarray | None]:
        """The refined rotation, and a translation when the stage solves one (else None)."""
        return inp.R_ray @ rot_z(inp.angle) @ inp.R_view, None


class PnPRefiner(BaseEstimator):
    """RANSAC PnP on the matched keypoints' 3-D points (rotation and translation).

    ``threshold``: reprojection error in pixels for a RANSAC inlier; below ``min_inliers``
    inliers, or when PnP's rotation is more than ``max_turn_deg`` from the homography answer (a
    degenerate solution: few points, one plane seen edge-on), the homography answer is kept. It
    is also kept (with the translation that fits it best) unless PnP lowers the MSAC cost, the
    sum over every correspondence of its squared reprojection distance capped at
    ``threshold``, by more than ``keep_margin`` px²: PnP's three extra degrees of freedom always
    fit a little better, a small object seen from afar constrains its tilt weakly, and a
    training view's exact tilt is then the better answer. A larger margin suits objects that
    rest on the table, a smaller one objects that lean; ``keep_margin=0`` keeps the training
    view only where it fits at least as well as PnP.
    ``correspondences="ratio"`` solves from every ratio-test pair of the matched training views
    (RANSAC PnP removes the outliers); ``"homography"`` only from the homography inliers, which
    drop true matches on curved or many-sided objects; ``"ratio+global"`` adds the query's
    matches against *every* training keypoint that pass a 3-D-aware ratio test
    (``global_ratio``, the second neighbour taken over ``merge_radius`` away: the matches
    ``sift-pnp`` solves from), which reach the training views around a pose that the few matched
    views miss, such as a tilt that no training view shows. Training views must carry
    ``View.depth``.
    """

    needs_depth = True

    def __init__(
        self,
        threshold: float = 3.0,
        min_inliers: int = 6,
        max_turn_deg: float = 45.0,
        keep_margin: float = 10.0,
        correspondences: str = "ratio",
        global_ratio: float = 0.8,
        merge_radius: float = 0.004,
    ):
        self.threshold = threshold
        self.min_inliers = min_inliers
        self.max_turn_deg = max_turn_deg
        self.keep_margin = keep_margin
        self.correspondences = correspondences
        self.global_ratio = global_ratio
        self.merge_radius = merge_radius

    def validate(self) -> None:
        if not self.threshold > 0:
            raise ValueError(f"threshold must be > 0 pixels, got {self.threshold}")
        if self.min_inliers < 6:
            raise ValueError(f"min_inliers must be >= 6 (PnP), got {self.min_inliers}")
        if not 0 < self.max_turn_deg <= 180:
            raise ValueError(f"max_turn_deg must be in (0, 180], got {self.max_turn_deg}")
        if not 0 <= self.keep_margin < np.inf:
            raise ValueError(f"keep_margin must be >= 0 squared pixels, got {self.keep_margin}")
        if self.correspondences not in _CORRESPONDENCES:
            raise ValueError(
                f"correspondences must be one of {list(_CORRESPONDENCES)}, "
                f"got {self.correspondences!r}"
            )
        if not 0 < self.global_ratio <= 1:
            raise ValueError(f"global_ratio must be in (0, 1], got {self.global_ratio}")
        if not self.merge_radius >= 0:
            raise ValueError(f"merge_radius must be >= 0 metres, got {self.merge_radius}")

    def refine(self, inp: RefinementInput) -> tuple[np.ndarray, np.ndarray | None]:
        fallback = inp.R_ray @ rot_z(inp.angle) @ inp.R_view
        if inp.db_xyz is None:
            return fallback, None
        n = inp.n_inliers if self.correspondences == "homography" else len(inp.db_rows)
        obj, img = inp.db_xyz[inp.db_rows[:n]], inp.xy[:n]
        if self.correspondences == "ratio+global" and inp.neighbours is not None:
            q, rows = ratio_test_3d(
                *inp.neighbours, inp.db_xyz, self.global_ratio, self.merge_radius
            )
            obj = np.concatenate([obj, inp.db_xyz[rows]])
            img = np.concatenate([img, np.asarray(inp.keypoints_xy, float)[q]])
        known = np.isfinite(obj).all(axis=1)
        if known.sum() < self.min_inliers:
            return fallback, None
        obj, img = obj[known], img[known]
        all_obj, all_img = obj, img
        R, t, inliers = pnp(obj, img, inp.camera, self.threshold, inp.seed)
        if R is None or inliers.sum() < self.min_inliers:
            return fallback, None
        # A near-planar set of points seen from afar fits two mirrored tilts almost equally
        # well; polish from the homography answer too, and keep the better fit (the nearer
        # to that answer when the two fit alike).
        obj, img = obj[inliers], img[inliers]
        candidates = [(R, t), _polish(obj, img, inp.camera, fallback, t)]
        errs = [_rms(obj, img, inp.camera, *c) for c in candidates]
        turns = [geodesic_deg(c[0][None], fallback[None])[0] for c in candidates]
        alike = abs(errs[0] - errs[1]) <= 0.1 * min(errs) + 0.05
        pick = int(np.argmin(turns)) if alike else int(np.argmin(errs))
        R, t = candidates[pick]
        if turns[pick] > self.max_turn_deg:
            return fallback, None
        # Score both on every correspondence, each with its own inliers (MSAC): on PnP's
        # inliers alone the comparison is biased towards PnP, whose RANSAC chose them.
        t_fallback = _translation_for(obj, img, inp.camera, fallback, t)
        for _ in range(2):
            near = _distances(all_obj, all_img, inp.camera, fallback, t_fallback) < self.threshold
            if near.sum() < self.min_inliers:
                break
            t_fallback = _translation_for(
                all_obj[near], all_img[near], inp.camera, fallback, t_fallback
            )
        cost_fallback = _msac_cost(all_obj, all_img, inp.camera, fallback, t_fallback,
                                   self.threshold)  # fmt: skip
        cost_pnp = _msac_cost(all_obj, all_img, inp.camera, R, t, self.threshold)
        if cost_fallback - cost_pnp <= self.keep_margin:
            return fallback, t_fallback
        return R, t


def _polish(obj, img, camera: CameraModel, R: np.ndarray, t: np.ndarray):
    """Levenberg-Marquardt refinement of the pose ``(R, t)`` on the correspondences."""
    rvec, tvec = cv2.solvePnPRefineLM(
        np.ascontiguousarray(obj, np.float64), np.ascontiguousarray(img, np.float64),
        np.asarray(camera.K, float), None, cv2.Rodrigues(np.asarray(R, float))[0],
        np.asarray(t, float).reshape(3, 1).copy(),
    )  # fmt: skip
    return cv2.Rodrigues(rvec)[0], tvec.ravel()


def _translation_for(obj, img, camera: CameraModel, R: np.ndarray, t0: np.ndarray) -> np.ndarray:
    """The translation that best reprojects ``obj`` onto ``img`` for a fixed rotation ``R``
    (Gauss-Newton on the three coordinates, from ``t0``)."""
    K = np.asarray(camera.K, float)
    fx, fy = K[0, 0], K[1, 1]
    t = np.asarray(t0, float).copy()
    rotated = obj @ R.T
    for _ in range(10):
        p = rotated + t
        if (p[:, 2] <= 1e-6).any():
            return np.asarray(t0, float)
        z = p[:, 2]
        r = np.r_[fx * p[:, 0] / z + K[0, 2] - img[:, 0], fy * p[:, 1] / z + K[1, 2] - img[:, 1]]
        J = np.zeros((2 * len(p), 3))
        J[: len(p), 0] = fx / z
        J[: len(p), 2] = -fx * p[:, 0] / z**2
        J[len(p) :, 1] = fy / z
        J[len(p) :, 2] = -fy * p[:, 1] / z**2
        step = np.linalg.lstsq(J, -r, rcond=None)[0]
        t += step
        if np.abs(step).max() < 1e-7:
            break
    return t


def _distances(obj, img, camera: CameraModel, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Reprojection distance of every point in pixels (inf behind the camera)."""
    cam = obj @ R.T + t
    uv = cam @ np.asarray(camera.K, float).T
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.linalg.norm(uv[:, :2] / uv[:, 2:] - img, axis=1)
    return np.where(cam[:, 2] > 0, d, np.inf)


def _msac_cost(obj, img, camera: CameraModel, R, t, threshold: float) -> float:
    """Sum of squared reprojection distances in px², each capped at ``threshold``: an outlier
    costs the same to either pose, so each pose is judged on its own inliers."""
    d = np.minimum(_distances(obj, img, camera, R, t), threshold)
    return float(np.sum(d**2))


def _rms(obj, img, camera: CameraModel, R: np.ndarray, t: np.ndarray) -> float:
    """Root-mean-square reprojection error in pixels (inf when a point is behind the camera)."""
    return float(np.sqrt(np.mean(_distances(obj, img, camera, R, t) ** 2)))
