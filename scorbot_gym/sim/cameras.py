"""Cameras as plain named specs: where they are, what they look at, their field of view."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class CameraSpec:
    """A fixed camera looking from ``pos`` at ``target`` (world frame, metres).

    ``up`` picks the image's up direction; ``fovy`` is the vertical field of view in degrees.
    """

    name: str
    pos: tuple[float, float, float]
    target: tuple[float, float, float]
    fovy: float
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)

    def xyaxes(self) -> list[float]:
        """MuJoCo's camera ``xyaxes``: camera x (image right) and y (image up) in the world."""
        forward = np.subtract(self.target, self.pos)
        forward /= np.linalg.norm(forward)
        right = np.cross(forward, self.up)
        if np.linalg.norm(right) < 1e-6:
            raise ValueError(f"camera {self.name!r}: 'up' is parallel to the viewing direction")
        right /= np.linalg.norm(right)
        up = np.cross(right, forward)
        return [*right.tolist(), *up.tolist()]


def intrinsics(fovy_deg: float, width: int, height: int) -> np.ndarray:
    """Pinhole K of a MuJoCo camera rendered at ``width`` x ``height`` (square pixels)."""
    f = 0.5 * height / np.tan(np.deg2rad(fovy_deg) / 2)
    # OpenCV puts pixel centres at integer coordinates, so the image centre is at (W-1)/2.
    return np.array([[f, 0.0, (width - 1) / 2], [0.0, f, (height - 1) / 2], [0.0, 0.0, 1.0]])


def world_from_camera(cam_pos: np.ndarray, cam_xmat: np.ndarray) -> np.ndarray:
    """OpenCV-convention extrinsics (x right, y down, z forward) from MuJoCo's camera frame.

    MuJoCo cameras look along their -z axis with y up; OpenCV's look along +z with y down, so the
    two frames differ by a 180-degree rotation about x.
    """
    T = np.eye(4)
    T[:3, :3] = np.asarray(cam_xmat).reshape(3, 3) @ np.diag([1.0, -1.0, -1.0])
    T[:3, 3] = cam_pos
    return T
