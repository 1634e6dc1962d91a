"""The other objects on the table as points a controller can keep its hand away from.

A pose source answers the target's pose; on a cluttered table a grasp planner also needs to
know where the *other* objects stand (:mod:`scorbot_gym.policies.grasp_clearance`). They travel
in the observation as a fixed-size set of points on the table plane, each with the height of
the object's top there (``neighbour_points``, ``(MAX_NEIGHBOUR_POINTS, 3)``, world metres;
``neighbour_valid`` marks the rows in use): the sampled occupancy of the neighbours' footprints,
what a depth camera's point cloud of the table would give, on a grid of :data:`GRID_PITCH`
(coarsened where the points would not fit). A footprint is sampled inside as well as on its
outline, so that a finger coming down wholly inside a large neighbour still meets points.

- From the ground truth (the ``oracle`` family; privileged, like the target's pose): each
  object's mesh under its true pose, the convex hull of its projection on the table.
- From a fixed camera looking down (``manifold_clutter``): each blob other than the target's,
  its pixels back-projected onto the table plane. An object's top seen from above lands a
  little farther from the camera's nadir than the object stands, so the blob's back-projection
  contains the footprint (the camera sees no object from below): conservative. A monocular
  camera measures no height: the blob is given the height of the tallest catalogue object it
  was recognised as, or :data:`UNKNOWN_HEIGHT` if none.
"""

from __future__ import annotations

import cv2
import numpy as np

#: rows of the ``neighbour_points`` observation entry
MAX_NEIGHBOUR_POINTS = 512
#: spacing (m) of the points sampled in a footprint (coarsened to fit MAX_NEIGHBOUR_POINTS)
GRID_PITCH = 0.01
#: height (m) above the table given to a blob of unknown class: taller than any catalogue object
UNKNOWN_HEIGHT = 0.25


def footprint_points(vertices: np.ndarray, table_z: float, pitch: float = GRID_PITCH) -> np.ndarray:
    """Points ``(N, 3)`` sampling the footprint of an object whose world vertices are
    ``vertices`` (the convex hull of their table-plane projection: a grid of ``pitch`` inside,
    and the hull's outline every ``pitch``), at the height of its top (at least ``table_z``)."""
    hull = cv2.convexHull(np.asarray(vertices[:, :2], np.float32))[:, 0].astype(float)
    xy = _fill_polygon(hull, pitch)
    top = max(float(vertices[:, 2].max()), table_z)
    return np.c_[xy, np.full(len(xy), top)]


def mask_points(
    mask: np.ndarray, camera, table_z: float, height: float, pitch: float = GRID_PITCH
) -> np.ndarray:
    """Points ``(N, 3)`` sampling a blob's back-projection onto the table plane (``camera``: a
    :class:`pose.camera.CameraModel`), one per ``pitch`` cell it covers, ``height`` above the
    table. The blob's outline is used, so the blob's holes (the arm cut through it) count too."""
    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    out = []
    for contour in contours:
        # the outline within a pixel: a staircase of one-pixel edges would fill the points
        uv = cv2.approxPolyDP(contour, 1.0, True)[:, 0].astype(float)
        xy = camera.backproject_to_plane(uv, table_z)[:, :2]
        out.append(_fill_polygon(xy, pitch))
    if not out:
        return np.zeros((0, 3))
    xy = np.vstack(out)
    return np.c_[xy, np.full(len(xy), table_z + height)]


def _fill_polygon(poly: np.ndarray, pitch: float) -> np.ndarray:
    """Grid points of ``pitch`` inside the polygon ``poly`` (``(K, 2)``, m) and points every
    ``pitch`` along its outline: a thin or small polygon keeps its outline."""
    lo = poly.min(axis=0)
    px = np.round((poly - lo) / pitch * 4).astype(np.int32)  # a raster 4x finer than the grid
    size = px.max(axis=0) + 1
    raster = np.zeros((int(size[1]), int(size[0])), np.uint8)
    cv2.fillPoly(raster, [px], 1)
    ys, xs = np.nonzero(raster[::4, ::4])
    inside = lo + np.c_[xs, ys] * pitch
    edges = np.roll(poly, -1, axis=0) - poly
    lengths = np.linalg.norm(edges, axis=1)
    outline = [
        poly[i] + edges[i] * t[:, None]
        for i in range(len(poly))
        for t in [np.arange(0.0, 1.0, pitch / lengths[i]) if lengths[i] > 0 else np.zeros(1)]
    ]
    return np.vstack([inside, *outline]) if outline else inside


def pack_points(
    points: np.ndarray, capacity: int = MAX_NEIGHBOUR_POINTS, pitch: float = GRID_PITCH
) -> tuple[np.ndarray, np.ndarray]:
    """``points`` as the observation's fixed-size ``(capacity, 3)`` array and its 0/1 validity
    mask: thinned to one point per grid cell (the highest), the cell doubled until they fit."""
    out = np.zeros((capacity, 3))
    valid = np.zeros(capacity)
    points = np.asarray(points, float).reshape(-1, 3)
    while len(points) > capacity:
        cells = np.floor(points[:, :2] / pitch).astype(np.int64)
        order = np.lexsort((-points[:, 2], cells[:, 1], cells[:, 0]))
        cells, points = cells[order], points[order]
        first = np.r_[True, (np.diff(cells, axis=0) != 0).any(axis=1)]
        points = points[first]
        pitch *= 2
    out[: len(points)] = points
    valid[: len(points)] = 1.0
    return out, valid
