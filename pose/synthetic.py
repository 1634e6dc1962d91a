"""Synthetic views with exactly known poses: a textured flat card on a table under a camera.

Used by the tests (and handy for quick experiments) where the full simulator would be slow or
is not needed: the image of a planar card is an exact homography of its texture.
"""

from __future__ import annotations

import cv2
import numpy as np

from pose.camera import CameraModel
from pose.rotations import rot_z
from pose.view import View


def card_texture(seed: int = 0, size: int = 200) -> np.ndarray:
    """A random, rotationally asymmetric RGB texture rich in SIFT features."""
    rng = np.random.default_rng(seed)
    tex = np.full((size, size, 3), 235, np.uint8)
    for _ in range(40):
        c = tuple(int(v) for v in rng.integers(0, 200, 3))
        p = tuple(int(v) for v in rng.integers(0, size, 2))
        kind = rng.integers(3)
        if kind == 0:
            cv2.circle(tex, p, int(rng.integers(3, 15)), c, -1)
        elif kind == 1:
            q = tuple(int(v) for v in rng.integers(0, size, 2))
            cv2.line(tex, p, q, c, int(rng.integers(1, 4)))
        else:
            letter = chr(int(rng.integers(65, 91)))
            cv2.putText(tex, letter, p, cv2.FONT_HERSHEY_SIMPLEX, 0.9, c, 2)
    cv2.rectangle(tex, (0, 0), (size - 1, size - 1), (20, 20, 20), 3)
    return tex


def top_camera(width: int = 320, height: int = 240, height_m: float = 0.6) -> CameraModel:
    """A camera ``height_m`` above the table origin looking straight down (OpenCV axes)."""
    f = 0.9 * width
    K = np.array([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1.0]])
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])  # x right, y down, z towards the table
    T[:3, 3] = [0.0, 0.0, height_m]
    return CameraModel(K=K, world_from_camera=T, width=width, height=height, name="top")


def card_pose(x: float, y: float, yaw: float, tilt: float = 0.0) -> np.ndarray:
    """``world_from_object`` of a card at ``(x, y)`` on the table turned by ``yaw``, and tilted
    by ``tilt`` radians about its own x axis (its centre stays on the table)."""
    T = np.eye(4)
    c, s = np.cos(tilt), np.sin(tilt)
    T[:3, :3] = rot_z(yaw) @ np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]])
    T[:3, 3] = [x, y, 0.0]
    return T


def render_card(
    texture: np.ndarray, camera: CameraModel, world_from_object: np.ndarray, side_m: float = 0.12
) -> tuple[np.ndarray, np.ndarray]:
    """Image (grey table + card) and the card's mask, for a card of side ``side_m``."""
    n = texture.shape[0]
    # texture pixel (i, j) -> object point ((i / n - 0.5) side, (j / n - 0.5) side, 0)
    S = np.array([[side_m / n, 0, -side_m / 2], [0, side_m / n, -side_m / 2], [0, 0, 1.0]])
    cam_from_obj = camera.camera_from_world @ world_from_object
    H = camera.K @ np.c_[cam_from_obj[:3, 0], cam_from_obj[:3, 1], cam_from_obj[:3, 3]] @ S
    size = (camera.width, camera.height)
    img = cv2.warpPerspective(texture, H, size, flags=cv2.INTER_LINEAR, borderValue=(90, 90, 90))
    mask = cv2.warpPerspective(np.full((n, n), 255, np.uint8), H, size, flags=cv2.INTER_NEAREST)
    return img, mask > 127


def card_depth(camera: CameraModel, world_from_object: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Depth (metres along the optical axis) of the card's plane inside ``mask``, 0 elsewhere:
    the ray through each pixel meets the plane ``z = 0`` of the object frame."""
    cam_from_obj = camera.camera_from_world @ world_from_object
    normal, origin = cam_from_obj[:3, 2], cam_from_obj[:3, 3]
    v, u = np.mgrid[0 : camera.height, 0 : camera.width]
    rays = np.stack([u, v, np.ones_like(u)], -1).astype(float) @ np.linalg.inv(camera.K).T
    z = (normal @ origin) / (rays @ normal)
    return np.where(mask, z, 0.0).astype(np.float32)


def card_views(
    poses_xy_yaw: np.ndarray, camera: CameraModel | None = None, texture_seed: int = 0
) -> tuple[list[View], np.ndarray]:
    """Views (with depth) and ``camera_from_object`` poses for rows ``(x, y, yaw)`` or
    ``(x, y, yaw, tilt)``."""
    camera = camera or top_camera()
    tex = card_texture(texture_seed)
    views, poses = [], []
    for row in np.asarray(poses_xy_yaw, float):
        T = card_pose(*row)
        img, mask = render_card(tex, camera, T)
        views.append(View(img, camera, mask, "card", card_depth(camera, T, mask)))
        poses.append(camera.camera_from_world @ T)
    return views, np.array(poses)
