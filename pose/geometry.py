"""Image and table geometry used by the estimator: object centre/size, table heights."""

from __future__ import annotations

import cv2
import numpy as np

from pose.camera import CameraModel


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
