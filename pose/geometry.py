"""Image and table geometry used by the estimators: object centre/size, table heights, keypoints
lifted to 3-D with a view's depth, and RANSAC PnP on 2-D-3-D correspondences."""

from __future__ import annotations

import cv2
import numpy as np

from pose.camera import CameraModel
from pose.view import View

MIN_MASK_PIXELS = 16


def centre_and_size(mask: np.ndarray | None, xy: np.ndarray) -> tuple[np.ndarray, float]:
    """Object centre (pixels) and size (pixels): mask centroid and sqrt(area) when a mask is
    given, else the keypoints' mean and twice their RMS radius."""
    if mask is not None:
        m = cv2.moments(np.asarray(mask, np.uint8), binaryImage=True)
        if m["m00"] > 0:
            return np.array([m["m10"] / m["m00"], m["m01"] / m["m00"]]), float(np.sqrt(m["m00"]))
    xy = np.asarray(xy, float)
    c = xy.mean(axis=0)
    r = float(np.sqrt(((xy - c) ** 2).sum(axis=1).mean()))
    return c, max(2.0 * r, 1.0)


def effective_height(camera: CameraModel, uv: np.ndarray, origin_world: np.ndarray) -> float:
    """Height of the point on the viewing ray through ``uv`` that lies above/below the object
    origin (closest in x-y). Intersecting a later centroid ray with this plane undoes the offset
    between the silhouette centroid and the origin for the same aspect."""
    o, d = camera.ray(np.asarray(uv, float)[None])
    d = d[0]
    dxy = d[:2]
    if dxy @ dxy < 1e-12:
        return float(origin_world[2])
    s = dxy @ (np.asarray(origin_world[:2]) - o[:2]) / (dxy @ dxy)
    return float(o[2] + s * d[2])


def camera_point(camera: CameraModel, world_point: np.ndarray) -> np.ndarray:
    T = camera.camera_from_world
    return T[:3, :3] @ np.asarray(world_point, float) + T[:3, 3]


def world_point(camera: CameraModel, camera_point_: np.ndarray) -> np.ndarray:
    T = camera.world_from_camera
    return T[:3, :3] @ np.asarray(camera_point_, float) + T[:3, 3]


def object_region(view: View) -> np.ndarray | None:
    """The object's visible pixels, or None when the view has no usable mask."""
    if view.mask is None:
        return None
    m = np.asarray(view.mask, bool)
    return m if np.count_nonzero(m) >= MIN_MASK_PIXELS else None


def lift_to_object(view: View, xy: np.ndarray, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Object-frame 3-D points of the keypoints ``xy`` with known depth, and which had one.

    The camera point ``z K^-1 (u, v, 1)`` is mapped by the inverse of the training pose.
    Depth is read at the rounded pixel; 0 (unknown, e.g. under an occluder) or a pixel outside
    the mask drops the point.
    """
    if view.depth is None:
        raise ValueError("training views need View.depth to lift keypoints to 3-D")
    h, w = view.depth.shape
    u = np.clip(np.rint(xy[:, 0]).astype(int), 0, w - 1)
    v = np.clip(np.rint(xy[:, 1]).astype(int), 0, h - 1)
    z = np.asarray(view.depth, float)[v, u]
    ok = np.isfinite(z) & (z > 0)
    region = object_region(view)
    if region is not None:  # a corner on the silhouette would take the table's depth
        ok &= region[v, u]
    rays = np.c_[xy, np.ones(len(xy))] @ np.linalg.inv(view.camera.K).T
    cam = rays * z[:, None]
    R, t = pose[:3, :3], pose[:3, 3]
    return (cam[ok] - t) @ R, ok  # R^T (p - t), row-wise


def pnp(
    obj: np.ndarray, img: np.ndarray, camera: CameraModel, threshold: float, seed: int
) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray]:
    """RANSAC PnP (EPnP hypotheses, iterative refinement on the inliers): ``R, t, inliers``.

    Returns ``(None, None, all-False)`` when OpenCV finds no pose or fewer than 6 matches.
    """
    none = np.zeros(len(obj), bool)
    if len(obj) < 6:
        return None, None, none
    cv2.setRNGSeed(int(seed))
    ok, rvec, tvec, inl = cv2.solvePnPRansac(
        np.ascontiguousarray(obj, np.float64),
        np.ascontiguousarray(img, np.float64),
        np.asarray(camera.K, float),
        None,
        iterationsCount=500,
        reprojectionError=threshold,
        confidence=0.999,
        flags=cv2.SOLVEPNP_EPNP,
    )
    if not ok or inl is None or len(inl) < 6:
        return None, None, none
    mask = none.copy()
    mask[inl.ravel()] = True
    rvec, tvec = cv2.solvePnPRefineLM(
        np.ascontiguousarray(obj[mask], np.float64),
        np.ascontiguousarray(img[mask], np.float64),
        np.asarray(camera.K, float),
        None,
        rvec,
        tvec,
    )
    R = cv2.Rodrigues(rvec)[0]
    t = tvec.ravel()
    if t[2] <= 0 or not np.isfinite(R).all():
        return None, None, none
    return R, t, mask
