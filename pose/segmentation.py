"""Object masks for a fixed camera by background subtraction.

A fixed eye-to-hand camera sees the same empty workspace every time, so a reference frame of
it (captured once per camera and lighting, before the object is placed) tells the object apart
by colour change alone: no model of the object, no simulator. The difference is measured in
CIE L*a*b* with lightness down-weighted, because a matte object and the table often differ
more in chroma than in brightness while small brightness changes (sensor noise, soft shading)
are the usual false positives. Speckle is dropped by the component-area test; the object is
the largest remaining connected component, with its enclosed holes filled. Opening and closing
(``kernel > 1``) are there for noisy cameras and off by default: an opening also erases the
thin strips of object that show between the gripper's fingers.

Pixels the caller knows are not the object (the robot arm, rendered from its own kinematic
model) are removed through ``exclude_mask`` after morphology (object and arm are still joined
then, so no slivers are opened away) and before the largest component is chosen.
"""

from __future__ import annotations

import cv2
import numpy as np
from sklearn.base import BaseEstimator
from sklearn.utils.validation import check_is_fitted

from pose.camera import CameraModel


def _as_rgb(image: np.ndarray, name: str) -> np.ndarray:
    img = np.asarray(image)
    if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"{name} must be an HxWx3 uint8 RGB image, got {img.dtype} {img.shape}")
    return img


def _lab(image: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(image.astype(np.float32) / 255.0, cv2.COLOR_RGB2Lab)


class BackgroundSubtractionSegmenter(BaseEstimator):
    """Foreground mask = pixels whose colour differs from a reference frame of the empty scene.

    Parameters
    ----------
    threshold : float
        Colour difference (weighted CIE76 Delta E; about 2.3 is a just-noticeable difference)
        above which a pixel is foreground.
    lightness_weight : float in [0, 1]
        Weight of the L* difference against a*, b*: below 1 it makes the test less sensitive
        to brightness-only changes (shading, soft shadows).
    kernel : int
        Side of the square structuring element (pixels) of the opening and closing; 1 (the
        default) turns morphology off.
    min_area : int
        Components smaller than this many pixels are not an object (the result is empty).
    exclude_dilation : int
        ``exclude_mask`` is grown by this many pixels first. 0 (the default) suits a mask
        rendered from the same model and calibration as the image; grow it when they may
        disagree by a pixel or so (a real camera's calibration error).
    fill_holes : bool
        Fill holes enclosed by the object's component (texture that happens to match the
        table's colour).

    Attributes
    ----------
    background_lab_ : ndarray (H, W, 3) float32, the reference frame in L*a*b*
    """

    def __init__(
        self,
        threshold: float = 10.0,
        lightness_weight: float = 0.5,
        kernel: int = 1,
        min_area: int = 30,
        exclude_dilation: int = 0,
        fill_holes: bool = True,
    ) -> None:
        self.threshold = threshold
        self.lightness_weight = lightness_weight
        self.kernel = kernel
        self.min_area = min_area
        self.exclude_dilation = exclude_dilation
        self.fill_holes = fill_holes

    def _check_params(self) -> None:
        if not (np.isfinite(self.threshold) and self.threshold > 0):
            raise ValueError(f"threshold must be a positive number, got {self.threshold!r}")
        if not 0.0 <= self.lightness_weight <= 1.0:
            raise ValueError(f"lightness_weight must be in [0, 1], got {self.lightness_weight!r}")
        for name in ("kernel", "min_area"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(f"{name} must be an int >= 1, got {value!r}")
        d = self.exclude_dilation
        if isinstance(d, bool) or not isinstance(d, (int, np.integer)) or d < 0:
            raise ValueError(f"exclude_dilation must be an int >= 0, got {d!r}")

    def fit(self, background_rgb: np.ndarray, y=None) -> BackgroundSubtractionSegmenter:
        """Store the reference frame (``HxWx3`` uint8 RGB) of the empty workspace."""
        self._check_params()
        self.background_lab_ = _lab(_as_rgb(background_rgb, "background_rgb"))
        return self

    def difference(self, rgb: np.ndarray) -> np.ndarray:
        """Per-pixel weighted colour difference to the reference frame, ``(H, W)`` float32."""
        check_is_fitted(self, "background_lab_")
        img = _as_rgb(rgb, "rgb")
        if img.shape != self.background_lab_.shape:
            raise ValueError(
                f"rgb is {img.shape[1]}x{img.shape[0]} but the background reference is "
                f"{self.background_lab_.shape[1]}x{self.background_lab_.shape[0]}"
            )
        d = _lab(img) - self.background_lab_
        d[..., 0] *= self.lightness_weight
        return np.sqrt((d * d).sum(axis=2))

    def foreground(self, rgb: np.ndarray, exclude_mask: np.ndarray | None = None) -> np.ndarray:
        """All changed pixels after opening and closing, minus excluded ones, ``(H, W)`` bool.

        Morphology runs on the raw change mask (object and arm still joined) and the excluded
        pixels go afterwards: opening after the removal would erase the thin strips of object
        that show beside the gripper.
        """
        fg = (self.difference(rgb) > self.threshold).astype(np.uint8)
        if self.kernel > 1:
            se = np.ones((self.kernel, self.kernel), np.uint8)
            fg = cv2.morphologyEx(fg, cv2.MORPH_OPEN, se)
            fg = cv2.morphologyEx(fg, cv2.MORPH_CLOSE, se)
        if exclude_mask is not None:
            ex = np.asarray(exclude_mask, dtype=bool)
            if ex.shape != fg.shape:
                raise ValueError(f"exclude_mask must have shape {fg.shape}, got {ex.shape}")
            ex = ex.astype(np.uint8)
            if self.exclude_dilation > 0:
                k = 2 * self.exclude_dilation + 1
                ex = cv2.dilate(ex, np.ones((k, k), np.uint8))
            fg[ex > 0] = 0
        return fg > 0

    def segment(self, rgb: np.ndarray, exclude_mask: np.ndarray | None = None) -> np.ndarray:
        """The object's mask: the largest foreground component, ``(H, W)`` bool.

        All ``False`` when no component reaches ``min_area`` (empty scene, object fully hidden).
        """
        fg = self.foreground(rgb, exclude_mask)
        return largest_component(fg, self.min_area, self.fill_holes, exclude_mask)


def largest_component(
    candidates: np.ndarray,
    min_area: int,
    fill: bool = True,
    exclude_mask: np.ndarray | None = None,
) -> np.ndarray:
    """The largest 8-connected component of ``candidates`` (bool), holes filled if ``fill``;
    all ``False`` when none reaches ``min_area``. Filling never puts ``exclude_mask`` back."""
    fg = np.asarray(candidates, dtype=np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(fg, connectivity=8)
    if n <= 1:
        return np.zeros(fg.shape, bool)
    areas = stats[1:, cv2.CC_STAT_AREA]
    best = int(np.argmax(areas)) + 1
    if areas[best - 1] < min_area:
        return np.zeros(fg.shape, bool)
    mask = labels == best
    if fill:
        mask = fill_holes(mask)
    if exclude_mask is not None:
        mask &= ~np.asarray(exclude_mask, dtype=bool)
    return mask


def components(
    candidates: np.ndarray,
    min_area: int,
    fill: bool = True,
    exclude_mask: np.ndarray | None = None,
) -> list[np.ndarray]:
    """Every 8-connected component of ``candidates`` (bool) of at least ``min_area`` pixels,
    largest first, each with its holes filled if ``fill``: the blobs of a scene with several
    objects (objects that touch in the image share one blob)."""
    fg = np.asarray(candidates, dtype=np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(fg, connectivity=8)
    areas = stats[1:, cv2.CC_STAT_AREA]
    out = []
    for i in np.argsort(-areas, kind="stable"):
        if areas[i] < min_area:
            break
        mask = labels == i + 1
        if fill:
            mask = fill_holes(mask)
        if exclude_mask is not None:
            mask &= ~np.asarray(exclude_mask, dtype=bool)
        out.append(mask)
    return out


def fill_holes(mask: np.ndarray) -> np.ndarray:
    """``mask`` with every background region not connected to the image border filled."""
    m = np.asarray(mask, dtype=np.uint8)
    padded = np.pad(m, 1)
    flood = padded.copy()
    cv2.floodFill(flood, np.zeros((flood.shape[0] + 2, flood.shape[1] + 2), np.uint8), (0, 0), 1)
    holes = flood[1:-1, 1:-1] == 0
    return (m > 0) | holes


def mask_iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two boolean masks (1.0 when both are empty)."""
    a, b = np.asarray(a, bool), np.asarray(b, bool)
    if a.shape != b.shape:
        raise ValueError(f"masks differ in shape: {a.shape} vs {b.shape}")
    union = np.logical_or(a, b).sum()
    return 1.0 if union == 0 else float(np.logical_and(a, b).sum() / union)


class HeightAboveTableSegmenter(BaseEstimator):
    """Object mask from a depth image: the pixels that stand above the table plane.

    Background subtraction needs a reference frame from the same viewpoint, so it cannot serve
    a camera that moves (on the arm). A depth image and the camera's calibration place every
    pixel in the world; the table is the most common height among them (a 2 mm histogram
    bin: the table fills most of a view of the workspace), and the object is what rises more
    than ``min_height`` above it. Excluded pixels (the arm, rendered from its model) go before
    the largest component is chosen, as in :class:`BackgroundSubtractionSegmenter`.

    Parameters
    ----------
    min_height : float
        Metres above the table plane for a pixel to count as object (depth noise, the table's
        own relief).
    min_area : int
        Components smaller than this many pixels are not an object (the result is empty).
    fill_holes : bool
        Fill holes enclosed by the object's component.
    """

    def __init__(self, min_height: float = 0.004, min_area: int = 30, fill_holes: bool = True):
        self.min_height = min_height
        self.min_area = min_area
        self.fill_holes = fill_holes

    def _check_params(self) -> None:
        if not (np.isfinite(self.min_height) and self.min_height > 0):
            raise ValueError(
                f"min_height must be a positive number of metres, got {self.min_height!r}"
            )
        a = self.min_area
        if isinstance(a, bool) or not isinstance(a, (int, np.integer)) or a < 1:
            raise ValueError(f"min_area must be an int >= 1, got {a!r}")

    def heights(self, depth: np.ndarray, camera: CameraModel) -> np.ndarray:
        """World height (z, metres) of every pixel, ``(H, W)``; NaN where there is no depth."""
        z = np.asarray(depth, dtype=np.float64)
        if z.ndim == 3 and z.shape[2] == 1:
            z = z[..., 0]
        if z.shape != (camera.height, camera.width):
            raise ValueError(
                f"depth is {z.shape[1]}x{z.shape[0]} but the camera is "
                f"{camera.width}x{camera.height}"
            )
        K = np.asarray(camera.K, float)
        v, u = np.mgrid[0 : z.shape[0], 0 : z.shape[1]]
        x = (u - K[0, 2]) / K[0, 0] * z
        y = (v - K[1, 2]) / K[1, 1] * z
        T = np.asarray(camera.world_from_camera, float)
        h = T[2, 0] * x + T[2, 1] * y + T[2, 2] * z + T[2, 3]
        h[~(np.isfinite(z) & (z > 0))] = np.nan
        return h

    @staticmethod
    def table_height(heights: np.ndarray, bin_m: float = 0.002) -> float:
        """The most common height: the table plane under a view of the workspace."""
        h = heights[np.isfinite(heights)]
        if h.size == 0:
            raise ValueError("the depth image has no valid pixel")
        lo = float(h.min())
        counts = np.bincount(((h - lo) / bin_m).astype(np.int64))
        return lo + (int(np.argmax(counts)) + 0.5) * bin_m

    def segment(
        self, depth: np.ndarray, camera: CameraModel, exclude_mask: np.ndarray | None = None
    ) -> np.ndarray:
        """The object's mask, ``(H, W)`` bool; all ``False`` when nothing rises high enough."""
        self._check_params()
        h = self.heights(depth, camera)
        above = np.nan_to_num(h, nan=-np.inf) > self.table_height(h) + self.min_height
        if exclude_mask is not None:
            ex = np.asarray(exclude_mask, dtype=bool)
            if ex.shape != above.shape:
                raise ValueError(f"exclude_mask must have shape {above.shape}, got {ex.shape}")
            above &= ~ex
        return largest_component(above, self.min_area, self.fill_holes, exclude_mask)
