"""Rotation helpers: a continuous 6-D representation, projection onto SO(3), ray frames."""

from __future__ import annotations

import numpy as np


def rot_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


_GENERIC = np.array([1.0, 2.0, 3.0]) / np.sqrt(14.0)


def inplane_heading(R: np.ndarray) -> float:
    """Image-plane angle (radians, image axes) of a fixed generic object direction under ``R``.

    It turns exactly with the object when the object turns about the optical axis, so
    ``rot_z(-inplane_heading(R)) @ R`` no longer depends on that turn. The direction
    ``(1, 2, 3)/sqrt(14)`` is oblique to every face of a box: with any face towards the camera
    at least 60 % of it lies in the image plane, so the angle is always well defined there.
    """
    d = np.asarray(R, float) @ _GENERIC
    return float(np.arctan2(d[1], d[0]))


def to_6d(R: np.ndarray) -> np.ndarray:
    """First two columns of ``R`` (``(..., 3, 3)`` -> ``(..., 6)``): no wrap-around jumps."""
    R = np.asarray(R, float)
    return np.concatenate([R[..., :, 0], R[..., :, 1]], axis=-1)


def project_to_so3(M: np.ndarray) -> np.ndarray:
    """Nearest rotation (Frobenius) to a 3x3 matrix, by SVD."""
    U, _, Vt = np.linalg.svd(np.asarray(M, float))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def from_6d(x: np.ndarray) -> np.ndarray:
    """Rotation from a (possibly noisy) 6-D vector: the nearest rotation to ``[a, b, a x b]``."""
    x = np.asarray(x, float)
    a, b = x[:3], x[3:6]
    a = a / max(np.linalg.norm(a), 1e-12)
    b = b - a * (a @ b)
    b = b / max(np.linalg.norm(b), 1e-12)
    return project_to_so3(np.c_[a, b, np.cross(a, b)])


def geodesic_deg(R1: np.ndarray, R2: np.ndarray) -> np.ndarray:
    """Angle (degrees) of ``R1 R2^T``; broadcasts over leading axes."""
    tr = np.einsum("...ij,...ij->...", np.asarray(R1, float), np.asarray(R2, float))
    return np.degrees(np.arccos(np.clip((tr - 1.0) / 2.0, -1.0, 1.0)))


def ray_rotation(K: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Smallest rotation taking the optical axis onto the viewing ray through pixel ``uv``.

    ``R_ray^T R`` is the *allocentric* rotation: the object's rotation as seen along the ray.
    Appearance depends on it, not on the camera-frame rotation, so the regressor learns it.
    """
    d = np.linalg.solve(np.asarray(K, float), np.r_[np.asarray(uv, float)[:2], 1.0])
    d /= np.linalg.norm(d)
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, d)
    s, c = np.linalg.norm(axis), float(z @ d)
    if s < 1e-12:
        return np.eye(3)
    k = axis / s
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + s * kx + (1 - c) * (kx @ kx)
