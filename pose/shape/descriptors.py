"""Shape descriptors of a binary silhouette: Fourier, MPEG-7 ART and affine moment invariants.

The three families are complementary, as in the seed paper: Fourier descriptors see only the
outer contour, the Angular Radial Transform (ART) sees the whole region (holes included) on a
polar grid, and the affine moment invariants summarise the region's mass distribution in a way
that survives shear as well. :func:`shape_descriptor` concatenates them into one float64 vector
of length 73 (``FOURIER_SLICE``, ``ART_SLICE``, ``AMI_SLICE`` index the blocks).

References
----------
* D. Zhang, G. Lu, "A comparative study of Fourier descriptors for shape representation and
  retrieval", ACCV 2002.
* ISO/IEC 15938-3 (MPEG-7 Visual), region-based shape descriptor (ART); W.-Y. Kim, Y.-S. Kim,
  "A region-based shape descriptor using Zernike moments", Signal Processing: Image
  Communication 16 (2000) - the ART section of the MPEG-7 XM.
* J. Flusser, T. Suk, "Pattern recognition by affine moment invariants", Pattern Recognition
  26(1) (1993) 167-174; J. Flusser, T. Suk, B. Zitova, "Moments and Moment Invariants in
  Pattern Recognition", Wiley 2009 (invariants I1-I6).
"""

from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np

N_FOURIER = 32
N_ART_ANGULAR = 12
N_ART_RADIAL = 3
N_ART = N_ART_ANGULAR * N_ART_RADIAL - 1  # F00 only normalises
N_AMI = 6
DESCRIPTOR_LENGTH = N_FOURIER + N_ART + N_AMI  # 73

FOURIER_SLICE = slice(0, N_FOURIER)
ART_SLICE = slice(N_FOURIER, N_FOURIER + N_ART)
AMI_SLICE = slice(N_FOURIER + N_ART, DESCRIPTOR_LENGTH)

# Contour samples for the FFT; 256 >> 2*17 keeps aliasing of the used harmonics negligible.
_CONTOUR_SAMPLES = 256
MIN_PIXELS = 9


def as_silhouette(mask: np.ndarray) -> np.ndarray:
    """Validate ``mask`` and return it as a 2-D bool array (nonzero = object).

    Raises ``ValueError`` saying what was wrong: not 2-D, non-finite values, or fewer than
    ``MIN_PIXELS`` foreground pixels (an empty silhouette has no shape).
    """
    arr = np.asarray(mask)
    if arr.ndim != 2:
        raise ValueError(
            f"a silhouette must be a 2-D mask (H, W) with nonzero = object, got shape {arr.shape}"
        )
    if arr.dtype.kind not in "biuf":
        raise ValueError(f"a silhouette must be bool or numeric, got dtype {arr.dtype}")
    if arr.dtype.kind == "f" and not np.all(np.isfinite(arr)):
        raise ValueError("a silhouette must not contain NaN or inf")
    fg = arr != 0
    count = int(fg.sum())
    if count < MIN_PIXELS:
        raise ValueError(
            f"a silhouette needs at least {MIN_PIXELS} foreground (nonzero) pixels, "
            f"got {count} in a {arr.shape[0]}x{arr.shape[1]} mask"
        )
    return fg


def _outer_contour(fg: np.ndarray) -> np.ndarray:
    """Outer boundary ``(N, 2)`` (x, y) of the largest connected component, counter-clockwise."""
    padded = np.pad(fg.astype(np.uint8), 1)  # objects touching the border still get closed
    contours, _ = cv2.findContours(padded, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    contour = max(contours, key=cv2.contourArea).reshape(-1, 2).astype(np.float64) - 1.0
    x, y = contour[:, 0], contour[:, 1]
    signed_area = 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)
    return contour[::-1] if signed_area < 0 else contour


def _resample_closed(points: np.ndarray, n: int) -> np.ndarray:
    """``n`` points equally spaced in arc length along the closed polygon ``points``."""
    closed = np.vstack([points, points[:1]])
    seg = np.hypot(*np.diff(closed, axis=0).T)
    arc = np.r_[0.0, np.cumsum(seg)]
    if arc[-1] <= 0:
        raise ValueError("the silhouette's contour has zero length")
    s = np.linspace(0.0, arc[-1], n, endpoint=False)
    return np.c_[np.interp(s, arc, closed[:, 0]), np.interp(s, arc, closed[:, 1])]


def fourier_descriptor(mask: np.ndarray, n: int = N_FOURIER) -> np.ndarray:
    """Contour Fourier descriptor: ``n`` magnitudes ``|F_k| / |F_1|``.

    The outer contour, resampled uniformly by arc length, is read as complex ``x + iy`` and
    transformed. Dropping ``F_0`` removes translation, dividing by ``|F_1|`` removes scale, and
    keeping magnitudes removes rotation and the start point. The ``n`` harmonics used are the
    lowest ones other than 0 and 1, alternating sides: ``k = 2, -1, 3, -2, 4, -3, ...``.
    """
    if n < 1 or n > _CONTOUR_SAMPLES // 2:
        raise ValueError(f"n must be in [1, {_CONTOUR_SAMPLES // 2}], got {n}")
    fg = as_silhouette(mask)
    z = _resample_closed(_outer_contour(fg), _CONTOUR_SAMPLES)
    spectrum = np.fft.fft(z[:, 0] + 1j * z[:, 1]) / _CONTOUR_SAMPLES
    mags = np.abs(spectrum)
    if mags[1] <= 1e-12:
        raise ValueError("the silhouette's contour is degenerate (first harmonic is zero)")
    order = [k for i in range(1, n + 1) for k in (i + 1, -i)][:n]
    return np.array([mags[k] for k in order], dtype=np.float64) / mags[1]


@lru_cache(maxsize=4)
def _supersample_offsets(factor: int) -> np.ndarray:
    step = 1.0 / factor
    g = (np.arange(factor) + 0.5) * step - 0.5
    return np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2)


def art_descriptor(mask: np.ndarray) -> np.ndarray:
    """MPEG-7 Angular Radial Transform: 35 magnitudes ``|F_nm| / |F_00|``, n < 3, m < 12.

    ``F_nm = sum over the unit disk of V*_nm(rho, theta) f(rho, theta)`` with
    ``V_nm = exp(j m theta) / (2 pi) * R_n(rho)``, ``R_0 = 1`` and ``R_n = 2 cos(pi n rho)``.
    The disk is centred on the silhouette's centroid with radius the farthest foreground pixel
    corner (translation and scale invariance); magnitudes give rotation invariance; ``F_00``
    (proportional to the area) normalises. Order: n-major, ``(0,1) ... (0,11), (1,0) ...``.
    Pixels are 2x2 supersampled so that small silhouettes still integrate smoothly.
    """
    fg = as_silhouette(mask)
    ys, xs = np.nonzero(fg)
    pts = np.c_[xs, ys].astype(np.float64)
    cx, cy = pts.mean(axis=0)
    sub = (pts[:, None, :] + _supersample_offsets(2)[None]).reshape(-1, 2)
    dx, dy = sub[:, 0] - cx, sub[:, 1] - cy
    r = np.hypot(dx, dy)
    radius = np.hypot(np.abs(xs - cx) + 0.5, np.abs(ys - cy) + 0.5).max()
    # exp(-j m theta) by repeated multiplication of exp(-j theta) = (dx - j dy) / r
    unit = np.where(r > 0, (dx - 1j * dy) / np.where(r > 0, r, 1.0), 1.0)
    angular = np.empty((N_ART_ANGULAR, len(r)), dtype=np.complex128)
    angular[0] = 1.0
    for m in range(1, N_ART_ANGULAR):
        angular[m] = angular[m - 1] * unit
    c1 = np.cos(np.pi * r / radius)
    radial = np.stack([np.ones_like(c1), 2.0 * c1, 2.0 * (2.0 * c1**2 - 1.0)])  # cos(2a)
    coeffs = np.abs(radial @ angular.T).ravel()  # (3, 12); the 1/(2 pi) cancels below
    return coeffs[1:] / coeffs[0]


def _central_moments(fg: np.ndarray, max_order: int = 4) -> dict[tuple[int, int], float]:
    ys, xs = np.nonzero(fg)
    vx = np.vander(xs - xs.mean(), max_order + 1, increasing=True)  # columns x^0 .. x^k
    vy = np.vander(ys - ys.mean(), max_order + 1, increasing=True)
    m = vx.T @ vy  # m[p, q] = sum x^p y^q
    return {(p, q): float(m[p, q]) for p in range(max_order + 1) for q in range(max_order + 1 - p)}


def affine_moment_invariants(mask: np.ndarray) -> np.ndarray:
    """Flusser-Suk affine moment invariants I1..I6, each as a signed root of its degree.

    I1-I4 are from Flusser & Suk (1993); I5 and I6 are the two 4th-order invariants of
    Flusser, Suk & Zitova (2009). Raw invariants span many orders of magnitude (I2 is a
    quartic in third-order moments), so each is returned as ``sign(I) |I|^(1/d)`` with d its
    degree in the central moments (2, 4, 3, 5, 2, 3). That is monotone, so invariance is kept,
    and all six become comparable in scale.
    """
    mu = _central_moments(as_silhouette(mask))
    m00 = mu[(0, 0)]
    u20, u11, u02 = mu[(2, 0)], mu[(1, 1)], mu[(0, 2)]
    u30, u21, u12, u03 = mu[(3, 0)], mu[(2, 1)], mu[(1, 2)], mu[(0, 3)]
    u40, u31, u22, u13, u04 = mu[(4, 0)], mu[(3, 1)], mu[(2, 2)], mu[(1, 3)], mu[(0, 4)]

    i1 = (u20 * u02 - u11**2) / m00**4
    i2 = (
        u30**2 * u03**2
        - 6 * u30 * u21 * u12 * u03
        + 4 * u30 * u12**3
        + 4 * u21**3 * u03
        - 3 * u21**2 * u12**2
    ) / m00**10
    i3 = (
        u20 * (u21 * u03 - u12**2) - u11 * (u30 * u03 - u21 * u12) + u02 * (u30 * u12 - u21**2)
    ) / m00**7
    i4 = (
        u20**3 * u03**2
        - 6 * u20**2 * u11 * u12 * u03
        - 6 * u20**2 * u02 * u21 * u03
        + 9 * u20**2 * u02 * u12**2
        + 12 * u20 * u11**2 * u21 * u03
        + 6 * u20 * u11 * u02 * u30 * u03
        - 18 * u20 * u11 * u02 * u21 * u12
        - 8 * u11**3 * u30 * u03
        - 6 * u20 * u02**2 * u30 * u12
        + 9 * u20 * u02**2 * u21**2
        + 12 * u11**2 * u02 * u30 * u12
        - 6 * u11 * u02**2 * u30 * u21
        + u02**3 * u30**2
    ) / m00**11
    i5 = (u40 * u04 - 4 * u31 * u13 + 3 * u22**2) / m00**6
    i6 = (u40 * u04 * u22 + 2 * u31 * u22 * u13 - u40 * u13**2 - u04 * u31**2 - u22**3) / m00**9
    raw = np.array([i1, i2, i3, i4, i5, i6], dtype=np.float64)
    degree = np.array([2.0, 4.0, 3.0, 5.0, 2.0, 3.0])
    return np.sign(raw) * np.abs(raw) ** (1.0 / degree)


def shape_descriptor(mask: np.ndarray) -> np.ndarray:
    """The 73-vector ``[Fourier 32 | ART 35 | AMI 6]`` (float64) of a binary silhouette.

    Invariant to translation, scale and rotation of the silhouette (the AMI block also to
    shear). ``mask`` is any 2-D array, nonzero = object; raises ``ValueError`` if it is not 2-D
    or has fewer than 9 foreground pixels.
    """
    fg = as_silhouette(mask)
    out = np.concatenate([fourier_descriptor(fg), art_descriptor(fg), affine_moment_invariants(fg)])
    return out.astype(np.float64, copy=False)


def block_weights(
    fourier: float = 1.0, art: float = 1.0, ami: float = 1.0, n_extra: int = 0
) -> np.ndarray:
    """Per-feature weights giving each descriptor block one weight (extra features get 1).

    Used to tune how much each block counts in a classifier's distance; the ART block is the
    most discriminative on rendered silhouettes (see ``pose.shape.evaluation``).
    """
    w = np.ones(DESCRIPTOR_LENGTH + n_extra)
    w[FOURIER_SLICE], w[ART_SLICE], w[AMI_SLICE] = fourier, art, ami
    return w


def shape_descriptors(masks) -> np.ndarray:
    """Stack :func:`shape_descriptor` over an iterable of masks into an ``(N, 73)`` array."""
    rows = [shape_descriptor(m) for m in masks]
    if not rows:
        return np.empty((0, DESCRIPTOR_LENGTH), dtype=np.float64)
    return np.vstack(rows)
