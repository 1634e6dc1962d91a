"""Synthetic silhouettes drawn with OpenCV, for tests, demos and sanity checks.

Each shape is a polygon in a unit frame; an affine map (rotation, scale, shear, translation)
is applied to the polygon *before* rasterising, so transformed silhouettes are exact rather
than resampled copies of a raster.
"""

from __future__ import annotations

import cv2
import numpy as np

from pose.shape.datasets import SilhouetteSet


def _circle(n: int = 96, rx: float = 1.0, ry: float = 1.0) -> np.ndarray:
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.c_[rx * np.cos(t), ry * np.sin(t)]


def _star(points: int = 5, inner: float = 0.45) -> np.ndarray:
    t = np.linspace(0, 2 * np.pi, 2 * points, endpoint=False) - np.pi / 2
    r = np.where(np.arange(2 * points) % 2 == 0, 1.0, inner)
    return np.c_[r * np.cos(t), r * np.sin(t)]


SHAPES: dict[str, np.ndarray] = {
    "ellipse": _circle(rx=1.0, ry=0.55),
    "rectangle": np.array([[-1, -0.5], [1, -0.5], [1, 0.5], [-1, 0.5]], float),
    "triangle": np.array([[-1, 0.8], [1, 0.8], [-0.2, -1]], float),
    "ell": np.array([[-1, -1], [0, -1], [0, 0.4], [1, 0.4], [1, 1], [-1, 1]], float),
    "star": _star(),
    "cross": np.array(
        [[-0.3, -1], [0.3, -1], [0.3, -0.3], [1, -0.3], [1, 0.3], [0.3, 0.3], [0.3, 1],
         [-0.3, 1], [-0.3, 0.3], [-1, 0.3], [-1, -0.3], [-0.3, -0.3]], float),
}  # fmt: skip


def synthetic_silhouette(
    kind: str,
    size: int = 96,
    angle_deg: float = 0.0,
    scale: float = 1.0,
    shear: float = 0.0,
    offset: tuple[float, float] = (0.0, 0.0),
) -> np.ndarray:
    """A ``size x size`` bool mask of shape ``kind`` (see ``SHAPES``).

    At ``scale=1`` the shape spans about 60 % of the image; ``shear`` is the x-shear factor
    applied before rotation; ``offset`` moves the shape in pixels.
    """
    if kind not in SHAPES:
        raise ValueError(f"unknown shape {kind!r}; valid: {', '.join(SHAPES)}")
    if size < 16:
        raise ValueError(f"size must be >= 16 pixels, got {size}")
    a = np.deg2rad(angle_deg)
    rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    A = rot @ np.array([[1.0, shear], [0.0, 1.0]]) * (0.3 * size * scale)
    pts = SHAPES[kind] @ A.T + np.array([size / 2 + offset[0], size / 2 + offset[1]])
    mask = np.zeros((size, size), np.uint8)
    # 4 fractional bits: sub-pixel vertex placement keeps small rotations smooth
    cv2.fillPoly(mask, [np.round(pts * 16).astype(np.int32)], 1, lineType=cv2.LINE_8, shift=4)
    return mask.astype(bool)


def synthetic_dataset(n_per_class: int = 20, size: int = 96, seed: int = 0) -> SilhouetteSet:
    """Random similarity-transformed (plus slight shear) copies of every shape in ``SHAPES``."""
    rng = np.random.default_rng(seed)
    masks, labels = [], []
    for kind in SHAPES:
        for _ in range(n_per_class):
            masks.append(
                synthetic_silhouette(
                    kind,
                    size,
                    angle_deg=rng.uniform(0, 360),
                    scale=rng.uniform(0.6, 1.0),
                    shear=rng.uniform(-0.15, 0.15),
                    offset=tuple(rng.uniform(-0.05, 0.05, 2) * size),
                )
            )
            labels.append(kind)
    return SilhouetteSet(masks, np.array(labels), np.arange(len(masks)).astype(str))
