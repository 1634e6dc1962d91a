"""Noticing that the object moved while no camera can estimate its pose.

During a grasp the arm hides the object from the top camera, and a small object is too few
pixels in a side camera for the pose estimator (a Duplo brick in a 320 x 240 side view has a
handful of keypoints). If the object is pushed then, the pose source stays invalid and the
controller grasps where the object was. Its silhouette is still there. Where the silhouette's
centre is now, against where the object's model at the last estimate would put it, says where
the object went: the model's silhouette is moved over the table plane until the two centres
meet (comparing like with like, so that an oblique view's top face does not bias it). The
same comparison, over turns about the vertical, gives the new heading (a push turns the object
too), where the object's silhouette changes with it: position-based servoing on what the
cameras can still tell.
"""

from __future__ import annotations

import cv2
import numpy as np

from pose.camera import CameraModel
from pose.recognition import view_is_clear


class SilhouetteMotion:
    """Position and heading of a moved object from a clear silhouette.

    ``min_shift_m``: the smallest move reported, above the centroid's own error (the centroid of
    an oblique view is not the projection of the object's centre); ``min_area``: pixels the
    silhouette needs, with no contact with the image border or the arm (``view_is_clear``).
    ``turns_deg``: the turns about the vertical, from the held heading, that are tried (a push
    turns the object as well as moving it); the turn whose model silhouette, placed as above,
    overlaps the observed one best (convex-hull IoU) is taken if it beats keeping the heading
    by ``min_gain`` (objects symmetric about the vertical never do). ``turns_deg=()`` keeps
    the held heading (the ablation).
    """

    def __init__(
        self,
        min_shift_m: float = 0.015,
        min_area: int = 30,
        turns_deg: tuple[float, ...] = tuple(range(-45, 46, 5)),
        min_gain: float = 0.02,
    ) -> None:
        if not (np.isfinite(min_shift_m) and min_shift_m > 0):
            raise ValueError(f"min_shift_m must be a positive number of metres, got {min_shift_m}")
        if int(min_area) < 1:
            raise ValueError(f"min_area must be >= 1 pixel, got {min_area}")
        turns = tuple(float(t) for t in turns_deg)
        if not all(np.isfinite(t) and abs(t) <= 180 for t in turns):
            raise ValueError(f"turns_deg must be finite angles within [-180, 180], got {turns_deg}")
        if not (np.isfinite(min_gain) and 0 <= min_gain < 1):
            raise ValueError(f"min_gain must be an IoU gain in [0, 1), got {min_gain}")
        self.min_shift_m = float(min_shift_m)
        self.min_area = int(min_area)
        self.turns_deg = turns
        self.min_gain = float(min_gain)

    def locate(
        self,
        mask: np.ndarray | None,
        excluded: np.ndarray | None,
        camera: CameraModel,
        held_position: np.ndarray,
        held_rotation: np.ndarray,
        model_points: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """Where a clear silhouette places the object (world position and rotation), moved or
        not, or ``None`` (no clear silhouette; a camera that cannot place it on the plane).
        ``model_points`` (object frame, e.g. its convex hull's vertices) give the silhouette
        expected at a pose."""
        if not view_is_clear(mask, excluded, min_area=self.min_area):
            return None
        ys, xs = np.nonzero(mask)
        observed = np.c_[xs, ys].astype(np.float32)
        held = np.asarray(held_position, float)
        held_R = np.asarray(held_rotation, float)
        points = np.asarray(model_points, float)
        try:
            target = camera.backproject_to_plane(_hull_centre(observed)[None], held[2])[0]
            candidates = []
            for turn in (0.0, *(t for t in self.turns_deg if t != 0)):
                R = _turn_about_z(np.deg2rad(turn)) @ held_R
                p = self._placed(camera, points @ R.T, held, target)
                candidates.append((_hull_iou(camera.project(points @ R.T + p), observed), p, R))
        except ValueError:  # a ray parallel to the plane: this camera cannot place it
            return None
        best = max(candidates, key=lambda c: c[0])
        if best[0] < candidates[0][0] + self.min_gain:  # no clear gain: keep the held heading
            best = candidates[0]
        _, p, R = best
        return (p, R) if np.all(np.isfinite(p)) else None

    def moved_pose(
        self,
        mask: np.ndarray | None,
        excluded: np.ndarray | None,
        camera: CameraModel,
        held_position: np.ndarray,
        held_rotation: np.ndarray,
        model_points: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """:meth:`locate`'s answer if it is at least ``min_shift_m`` from ``held_position``
        (the object moved), else ``None``."""
        found = self.locate(mask, excluded, camera, held_position, held_rotation, model_points)
        if found is None or not self.is_move(found[0], held_position):
            return None
        return found

    def is_move(self, position: np.ndarray, held_position: np.ndarray) -> bool:
        shift = np.asarray(position, float)[:2] - np.asarray(held_position, float)[:2]
        return bool(np.linalg.norm(shift) >= self.min_shift_m)

    @staticmethod
    def _placed(
        camera: CameraModel, body: np.ndarray, held: np.ndarray, target: np.ndarray
    ) -> np.ndarray:
        """Slide ``body`` (rotated model points) over the plane at the held height until its
        silhouette's centre backprojects onto ``target``, the observed centre's."""
        z = float(held[2])
        p = held.copy()
        for _ in range(4):  # a fixed point: the projection is smooth and nearly affine here
            expected = _hull_centre(camera.project(body + p).astype(np.float32))
            step = target - camera.backproject_to_plane(expected[None], z)[0]
            p[:2] += step[:2]
            if np.linalg.norm(step[:2]) < 1e-4:
                break
        return p


def _turn_about_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _hull_iou(a_uv: np.ndarray, b_uv: np.ndarray) -> float:
    """IoU of the filled convex hulls of two point sets (pixels), rasterised around both."""
    hulls = [cv2.convexHull(np.asarray(uv, np.float32)).reshape(-1, 2) for uv in (a_uv, b_uv)]
    both = np.vstack(hulls)
    if not np.all(np.isfinite(both)):
        return 0.0
    lo = np.floor(both.min(0)) - 1
    w, h = (np.ceil(both.max(0)) - lo + 2).astype(int)
    if w * h > 4_000_000:  # a model projected through the camera's centre: no overlap to score
        return 0.0
    filled = []
    for hull in hulls:
        img = np.zeros((h, w), np.uint8)
        cv2.fillConvexPoly(img, np.round(hull - lo).astype(np.int32), 1)
        filled.append(img.astype(bool))
    union = np.count_nonzero(filled[0] | filled[1])
    return float(np.count_nonzero(filled[0] & filled[1]) / union) if union else 0.0


def _hull_centre(points_uv: np.ndarray) -> np.ndarray:
    """Area centroid of the convex hull of image points (pixels)."""
    hull = cv2.convexHull(points_uv)
    m = cv2.moments(hull)
    if m["m00"] <= 0:
        return points_uv.mean(0).astype(float)
    return np.array([m["m10"] / m["m00"], m["m01"] / m["m00"]])


_MOTION = {"silhouette": SilhouetteMotion}


def motion_names() -> tuple[str, ...]:
    return tuple(sorted(_MOTION))


def make_motion(motion: str | SilhouetteMotion | None) -> SilhouetteMotion | None:
    """A motion detector by name (``"silhouette"``), as is, or ``None`` (none)."""
    if motion is None or not isinstance(motion, str):
        return motion
    if motion not in _MOTION:
        raise ValueError(f"unknown motion detector {motion!r}; valid: {', '.join(motion_names())}")
    return _MOTION[motion]()
