"""Whether a camera's line of sight to the target object is clear: ground truth for scoring.

The arm hides the object from the top camera for much of a grasp, so the share of valid pose
estimates over a whole episode says as much about the arm's path as about the estimator.
:func:`object_visibility` tells the two apart: rays from the camera's centre to points of the
object (its geoms' bounding-box centres and their corners pulled 20 % inwards, so that none lies
on the table) count as clear unless another rendered geom (the arm, a distractor) is hit first.
It is geometry, not a render: a few ``mj_ray`` calls (microseconds each). The field of view is
not considered: an object outside the frame is not "hidden".
"""

from __future__ import annotations

import itertools

import mujoco
import numpy as np

# Geom groups the cameras render (MuJoCo's default visual groups); collision-only geoms in
# other groups hide nothing from a camera.
RENDERED_GROUPS = np.array([1, 1, 1, 0, 0, 0], np.uint8)
_CORNER_SCALE = 0.8  # corners pulled towards the centre: inside the object, off the table
_CORNERS = np.array(list(itertools.product((-1.0, 1.0), repeat=3))) * _CORNER_SCALE


def object_points(model: mujoco.MjModel, data: mujoco.MjData, geoms: np.ndarray) -> np.ndarray:
    """``(N, 3)`` world points of the object: per geom, its bounding box's centre and corners."""
    pts = []
    for g in geoms:
        centre, half = model.geom_aabb[g, :3], model.geom_aabb[g, 3:]
        local = np.vstack([centre, centre + _CORNERS * half])
        pts.append(data.geom_xpos[g] + local @ data.geom_xmat[g].reshape(3, 3).T)
    return np.vstack(pts)


def object_visibility(
    model: mujoco.MjModel, data: mujoco.MjData, camera_id: int, geoms: np.ndarray
) -> float:
    """Share of the object's points (:func:`object_points`) that ``camera_id`` sees with
    nothing but the object itself in the way, in [0, 1]."""
    origin = data.cam_xpos[camera_id].copy()
    hit = np.zeros(1, np.int32)
    own = set(int(g) for g in geoms)
    points = object_points(model, data, geoms)
    clear = 0
    for p in points:
        # distances are in units of (p - origin): a hit before 1 is in front of the point
        dist = mujoco.mj_ray(model, data, origin, p - origin, RENDERED_GROUPS, 1, -1, hit)
        clear += dist < 0 or dist >= 1.0 or int(hit[0]) in own
    return clear / len(points)
