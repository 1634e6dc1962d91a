"""Pinhole camera model in the OpenCV convention (x right, y down, z forward)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class CameraModel:
    """Intrinsics ``K`` (3x3) and extrinsics ``world_from_camera`` (4x4) of one image size."""

    K: np.ndarray
    world_from_camera: np.ndarray
    width: int
    height: int
    name: str = ""

    def __post_init__(self) -> None:
        if np.shape(self.K) != (3, 3):
            raise ValueError(f"K must be 3x3, got shape {np.shape(self.K)}")
        if np.shape(self.world_from_camera) != (4, 4):
            raise ValueError(
                f"world_from_camera must be 4x4, got shape {np.shape(self.world_from_camera)}"
            )
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"image size must be positive, got {self.width}x{self.height}")

    @property
    def camera_from_world(self) -> np.ndarray:
        R = self.world_from_camera[:3, :3]
        t = self.world_from_camera[:3, 3]
        out = np.eye(4)
        out[:3, :3] = R.T
        out[:3, 3] = -R.T @ t
        return out

    def project(self, points_world: np.ndarray) -> np.ndarray:
        """Pixel coordinates ``(N, 2)`` (u right, v down) of world points ``(N, 3)``."""
        p = np.atleast_2d(np.asarray(points_world, dtype=float))
        cam = p @ self.camera_from_world[:3, :3].T + self.camera_from_world[:3, 3]
        uvw = cam @ self.K.T
        return uvw[:, :2] / uvw[:, 2:3]

    def ray(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World origin and unit directions ``(N, 3)`` of the rays through pixels ``(N, 2)``."""
        uv = np.atleast_2d(np.asarray(uv, dtype=float))
        homog = np.c_[uv, np.ones(len(uv))]
        d_cam = homog @ np.linalg.inv(self.K).T
        d_world = d_cam @ self.world_from_camera[:3, :3].T
        d_world /= np.linalg.norm(d_world, axis=1, keepdims=True)
        return self.world_from_camera[:3, 3].copy(), d_world

    def backproject_to_plane(self, uv: np.ndarray, plane_z: float) -> np.ndarray:
        """World points ``(N, 3)`` where the rays through ``uv`` meet the plane ``z = plane_z``."""
        origin, d = self.ray(uv)
        if np.any(np.abs(d[:, 2]) < 1e-9):
            raise ValueError("a ray is parallel to the plane; cannot back-project")
        s = (plane_z - origin[2]) / d[:, 2]
        return origin + s[:, None] * d

    def to_dict(self) -> dict:
        return {
            "K": np.asarray(self.K).tolist(),
            "world_from_camera": np.asarray(self.world_from_camera).tolist(),
            "width": int(self.width),
            "height": int(self.height),
            "name": self.name,
        }

    @classmethod
    def from_dict(cls, d: dict) -> CameraModel:
        return cls(
            K=np.asarray(d["K"], dtype=float),
            world_from_camera=np.asarray(d["world_from_camera"], dtype=float),
            width=int(d["width"]),
            height=int(d["height"]),
            name=str(d.get("name", "")),
        )
