"""Noticing that the object moved while no camera can estimate its pose.

During a grasp the arm hides the object from the top camera, and a small object is too few
pixels in a side camera for the pose estimator (a Duplo brick in a 320 x 240 side view has a
handful of keypoints). If the object is pushed then, the pose source stays invalid and the
controller grasps where the object was. Its silhouette is still there. Where the silhouette's
centre is now, against where the object's model at the last estimate would put it, says where
the object went: the model's silhouette is moved over the table plane until the two centres
meet (comparing like with like, so that an oblique view's top face does not bias it). The
answer keeps the last estimate's rotation: position-based servoing on what the cameras can
still tell.
"""

from __future__ import annotations

import cv2
import numpy as np

from pose.camera import CameraModel
from pose.recognition import view_is_clear


class SilhouetteMotion:
    """Position of a moved object from a clear silhouette.

    ``min_shift_m``: the smallest move reported, above the centroid's own error (the centroid of
    an oblique view is not the projection of the object's centre); ``min_area``: pixels the
    silhouette needs, with no contact with the image border or the arm (``view_is_clear``).
    """

    def __init__(self, min_shift_m: float = 0.015, min_area: int = 30) -> None:
        if not (np.isfinite(min_shift_m) and min_shift_m > 0):
            raise ValueError(f"min_shift_m must be a positive number of metres, got {min_shift_m}")
        if int(min_area) < 1:
            raise ValueError(f"min_area must be >= 1 pixel, got {min_area}")
        self.min_shift_m = float(min_shift_m)
        self.min_area = int(min_area)

    def moved_position(
        self,
        mask: np.ndarray | None,
        excluded: np.ndarray | None,
        camera: CameraModel,
        held_position: np.ndarray,
        held_rotation: np.ndarray,
        model_points: np.ndarray,
    ) -> np.ndarray | None:
        """The object's new world position, or ``None`` (no clear silhouette, or no move
        beyond ``min_shift_m`` from ``held_position``). ``model_points`` (object frame, e.g.
        its convex hull's vertices) give the silhouette expected at a position."""
        if not view_is_clear(mask, excluded, min_area=self.min_area):
            return None
        ys, xs = np.nonzero(mask)
        observed = _hull_centre(np.c_[xs, ys].astype(np.float32))
        held = np.asarray(held_position, float)
        body = np.asarray(model_points, float) @ np.asarray(held_rotation, float).T
        z = float(held[2])
        p = held.copy()
        try:
            target = camera.backproject_to_plane(observed[None], z)[0]
            for _ in range(4):  # a fixed point: the projection is smooth and nearly affine here
                expected = _hull_centre(camera.project(body + p).astype(np.float32))
                step = target - camera.backproject_to_plane(expected[None], z)[0]
                p[:2] += step[:2]
                if np.linalg.norm(step[:2]) < 1e-4:
                    break
        except ValueError:  # a ray parallel to the plane: this camera cannot place it
            return None
        if not np.all(np.isfinite(p)) or np.linalg.norm(p[:2] - held[:2]) < self.min_shift_m:
            return None
        return p


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
