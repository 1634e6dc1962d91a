"""Stage a: SIFT keypoints with unit-length descriptors, restricted to the object's mask.

:class:`SiftKeypoints` is the stage object that :class:`pose.manifold.PoseManifoldEstimator`
composes; :func:`extract_sift` is the function it wraps.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass

import cv2
import numpy as np
from sklearn.base import BaseEstimator

CROP_MARGIN = 24


@dataclass(frozen=True)
class Features:
    """Keypoint locations ``xy`` ``(N, 2)`` (pixels), unit descriptors ``(N, 128)`` and SIFT
    orientations ``angles`` ``(N,)`` (radians, image axes: from u towards v, like
    ``arctan2(dv, du)``; zeros when not given)."""

    xy: np.ndarray
    descriptors: np.ndarray
    angles: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.angles is None:
            object.__setattr__(self, "angles", np.zeros(len(self.xy), np.float32))

    def __len__(self) -> int:
        return len(self.xy)

    def subset(self, keep: np.ndarray) -> Features:
        return Features(self.xy[keep], self.descriptors[keep], self.angles[keep])

    @classmethod
    def empty(cls) -> Features:
        return cls(np.zeros((0, 2), np.float32), np.zeros((0, 128), np.float32))


def to_gray(image: np.ndarray) -> np.ndarray:
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] == 3:
        return cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    return img.reshape(img.shape[:2])


_SHARED: ContextVar[dict | None] = ContextVar("shared_keypoints", default=None)


@contextmanager
def shared_keypoints() -> Iterator[None]:
    """Within the block, SIFT asked again for the same pixels, mask and settings returns the
    features it extracted the first time (read-only arrays), instead of detecting them again.

    Model selection fits every candidate on every fold but one and predicts the remaining
    fold: with two keypoint candidates and four folds each training view's SIFT would run nine
    times, though it is a function of the pixels alone (a large part of a selection's
    training time). The sharing is scoped to a block, not global, so that timing ``predict``
    never reads features an earlier call computed, and the memory goes with the block. Nested
    blocks share the outermost one's features.
    """
    token = _SHARED.set({}) if _SHARED.get() is None else None
    try:
        yield
    finally:
        if token is not None:
            _SHARED.reset(token)


def _digest(image: np.ndarray, mask: np.ndarray | None) -> bytes:
    h = hashlib.blake2b(digest_size=16)
    for a in (image, mask):
        if a is None:
            h.update(b"none")
        else:
            a = np.ascontiguousarray(a)
            h.update(f"{a.dtype.str}{a.shape}".encode())
            h.update(a.data)
    return h.digest()


def extract_sift(
    image: np.ndarray,
    mask: np.ndarray | None = None,
    n_features: int = 0,
    contrast_threshold: float = 0.04,
    mask_dilation: int = 2,
    upscale: float = 1.0,
) -> Features:
    """Detect SIFT keypoints (inside ``mask`` when given) and L2-normalise their descriptors.

    The mask is dilated by ``mask_dilation`` pixels so that corners on the silhouette, whose
    support straddles the boundary, are kept. With a mask, only its bounding box (plus a
    ``CROP_MARGIN`` border) is processed: the cost follows the object's size, not the image's.
    ``upscale`` > 1 enlarges that crop (bicubic) before detection, for objects only a few dozen
    pixels across: SIFT's finest octave is then finer than the image's pixels, and the
    locations are mapped back to image pixels. Inside a :func:`shared_keypoints` block a repeated
    call returns the first one's features.
    """
    if not upscale >= 1.0:
        raise ValueError(f"upscale must be >= 1 (1: the image as it is), got {upscale}")
    settings = (n_features, contrast_threshold, mask_dilation, upscale)
    memo = _SHARED.get()
    if memo is None:
        return _detect_sift(image, mask, *settings)
    key = (_digest(image, mask), settings)
    found = memo.get(key)
    if found is None:
        found = _detect_sift(image, mask, *settings)
        for a in (found.xy, found.descriptors, found.angles):
            a.flags.writeable = False  # shared by every caller: nobody may change it
        memo[key] = found
    return found


def _detect_sift(
    image: np.ndarray,
    mask: np.ndarray | None,
    n_features: int,
    contrast_threshold: float,
    mask_dilation: int,
    upscale: float,
) -> Features:
    gray = to_gray(image)
    cv_mask = None
    x0 = y0 = 0
    if mask is not None:
        m = np.asarray(mask).astype(np.uint8) * 255
        x, y, w, h = cv2.boundingRect(m)  # much faster than np.nonzero on a full frame
        if w == 0 or h == 0:
            return Features.empty()
        pad = CROP_MARGIN + mask_dilation
        y0, x0 = max(y - pad, 0), max(x - pad, 0)
        gray, m = gray[y0 : y + h + pad, x0 : x + w + pad], m[y0 : y + h + pad, x0 : x + w + pad]
        if mask_dilation > 0:
            m = cv2.dilate(m, np.ones((2 * mask_dilation + 1,) * 2, np.uint8))
        cv_mask = m
    if upscale != 1.0:
        gray = cv2.resize(gray, None, fx=upscale, fy=upscale, interpolation=cv2.INTER_CUBIC)
        if cv_mask is not None:
            size = (gray.shape[1], gray.shape[0])
            cv_mask = cv2.resize(cv_mask, size, interpolation=cv2.INTER_NEAREST)
    sift = cv2.SIFT_create(nfeatures=n_features, contrastThreshold=contrast_threshold)
    kps, desc = sift.detectAndCompute(np.ascontiguousarray(gray), cv_mask)
    if desc is None or len(kps) == 0:
        return Features.empty()
    xy = np.array([k.pt for k in kps], dtype=np.float32)
    if upscale != 1.0:  # cv2.resize keeps pixel centres aligned: x_big + 0.5 = f (x + 0.5)
        xy = (xy + 0.5) / np.float32(upscale) - 0.5
    xy += np.float32([x0, y0])
    angles = np.radians(np.array([k.angle for k in kps], dtype=np.float32))  # degrees, u -> v
    desc = desc.astype(np.float32)
    desc /= np.maximum(np.linalg.norm(desc, axis=1, keepdims=True), 1e-12)
    return Features(xy, desc, angles)


class SiftKeypoints(BaseEstimator):
    """Keypoint stage: SIFT inside the (dilated) mask.

    Training views keep the ``max_train_features`` strongest keypoints (0 = all): they fill the
    descriptor database that every query is matched against, so capping them bounds the index
    size and the matching time. Query views keep all their keypoints, since occlusion may leave
    only weak ones. ``contrast_threshold`` is SIFT's (lower finds more keypoints on faint
    texture). ``upscale`` enlarges the object's crop before detection (see :func:`extract_sift`):
    for cameras in which the objects are small.
    """

    def __init__(
        self,
        contrast_threshold: float = 0.03,
        max_train_features: int = 200,
        mask_dilation: int = 2,
        upscale: float = 1.0,
    ):
        self.contrast_threshold = contrast_threshold
        self.max_train_features = max_train_features
        self.mask_dilation = mask_dilation
        self.upscale = upscale

    def validate(self) -> None:
        if self.contrast_threshold <= 0:
            raise ValueError(f"contrast_threshold must be > 0, got {self.contrast_threshold}")
        if not self.upscale >= 1.0:
            raise ValueError(f"upscale must be >= 1 (1: the image as it is), got {self.upscale}")
        if self.max_train_features < 0 or self.mask_dilation < 0:
            raise ValueError(
                "max_train_features and mask_dilation must be >= 0, got "
                f"{self.max_train_features} and {self.mask_dilation}"
            )

    def extract(
        self, image: np.ndarray, mask: np.ndarray | None, training: bool = False
    ) -> Features:
        n = self.max_train_features if training else 0
        return extract_sift(
            image, mask, n, self.contrast_threshold, self.mask_dilation, self.upscale
        )
