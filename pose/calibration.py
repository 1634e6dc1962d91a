"""Refine a fixed camera's extrinsics from the silhouette of a known body that moves in its view.

An eye-to-hand camera is calibrated once; an error of a degree or a few millimetres moves every
estimate the camera makes by a centimetre, and a grasp planned from it closes off-centre. A
robot arm is a known body at a known pose (its kinematic model and encoders): rendered with
the camera's calibration, its silhouette should fall where the image shows it. Where it does
not, the difference measures the calibration error, at every step and at the depths the arm
passes through, so the camera can be re-calibrated while the task runs (the model-based
silhouette tracking of Drummond & Cipolla's RAPiD, applied to the camera instead of the body).

:class:`SilhouetteExtrinsicsFilter` keeps a maximum a posteriori estimate of a small correction
``delta = (v, w)`` of the camera pose (translation ``v`` in metres and rotation vector ``w`` in
radians, in the camera frame: ``world_from_camera = nominal @ exp(delta)``). Each
:meth:`~SilhouetteExtrinsicsFilter.update` takes the body's silhouette and depth rendered with
the current :attr:`~SilhouetteExtrinsicsFilter.camera` and the observed foreground: along the
normal of each predicted contour point it finds the observed silhouette edge, and the normal
distances are linear in ``delta`` through the point's image Jacobian. The measurements of all
updates are accumulated in information form with a Gaussian prior (the calibration's expected
accuracy) and a forgetting factor (each frame is linearised about the estimate of its time, so
the early ones, taken about a camera still far off, fade), so the estimate sharpens as the body
moves, and a frame that shows little changes little. Images, masks and camera models in;
nothing here knows the robot.
"""

from __future__ import annotations

import cv2
import numpy as np
from sklearn.base import BaseEstimator

from pose.camera import CameraModel


def _skew(p: np.ndarray) -> np.ndarray:
    """``(N, 3, 3)`` cross-product matrices of ``(N, 3)`` vectors."""
    out = np.zeros((len(p), 3, 3))
    out[:, 0, 1], out[:, 0, 2] = -p[:, 2], p[:, 1]
    out[:, 1, 0], out[:, 1, 2] = p[:, 2], -p[:, 0]
    out[:, 2, 0], out[:, 2, 1] = -p[:, 1], p[:, 0]
    return out


def _grey(image: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """``image`` (RGB or grey, uint8) as float grey levels, checked against ``shape``."""
    img = np.asarray(image)
    if img.shape[:2] != shape or img.ndim not in (2, 3) or img.dtype != np.uint8:
        raise ValueError(
            f"image must be a uint8 RGB or grey image of the masks' shape {shape}, got "
            f"{img.dtype} {img.shape}"
        )
    return (cv2.cvtColor(img, cv2.COLOR_RGB2GRAY) if img.ndim == 3 else img).astype(np.float32)


def se3_exp(delta: np.ndarray) -> np.ndarray:
    """The 4x4 transform of a small correction ``(v, w)``: rotation ``exp([w]x)`` (Rodrigues),
    translation ``v``."""
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.asarray(delta[3:], float).reshape(3, 1))[0]
    T[:3, 3] = delta[:3]
    return T


def corrected(camera: CameraModel, delta: np.ndarray) -> CameraModel:
    """``camera`` with its pose corrected by ``delta`` (camera frame)."""
    T = np.asarray(camera.world_from_camera, float) @ se3_exp(delta)
    return CameraModel(camera.K, T, camera.width, camera.height, camera.name)


class SilhouetteExtrinsicsFilter(BaseEstimator):
    """Recursive MAP estimate of a camera's extrinsics correction from a known body's silhouette.

    Parameters
    ----------
    prior_pos_m, prior_rot_deg
        Standard deviation of the calibration error expected per axis (translation, rotation):
        the Gaussian prior that holds the estimate at the nominal calibration until the images
        say otherwise.
    pixel_sigma
        Standard deviation of one contour point's edge distance, in pixels.
    effective_points
        How many independent measurements one frame's contour is worth: neighbouring contour
        points share their errors (the same edge, the same shading), so a frame's information
        is scaled to this many points however many are sampled.
    memory_frames
        How many recent frames the estimate rests on (an exponential forgetting factor of
        ``1 - 1 / memory_frames``): each frame is measured at the estimate of its time, so the
        early frames, linearised about a camera still far off, must give way to later ones.
    search_px
        How far along each normal the observed edge is looked for, in pixels either side.
    max_points
        Contour points sampled per frame (evenly along the contour).
    huber_px
        Residuals beyond this (pixels) are down-weighted (Huber): an edge that belongs to
        something else (the object beside the arm) must not pull the camera.
    contrast
        With an ``image``, the grey-level step (of 255) the image must show across an observed
        silhouette edge for it to count: a foreground edge without one is not the body's
        outline in this image (where the body stood when the reference frame was taken, the
        change mask has an edge that the current image does not).
    border_px
        Contour points this close to the image border are skipped (the silhouette is cut there).
    reject_px
        Residuals from the frame's own fit beyond this (pixels) get no weight (Tukey's
        biweight, after a first Huber fit; ``None``: Huber only). An edge many pixels off is
        another edge: a pale part of the body that the change mask missed against a pale
        table, or another body's. Huber bounds each one's pull, but a bounded pull that is
        always to the same side still moves the estimate by millimetres.
    min_points
        A frame with fewer usable contour points is skipped: a few points on one side of the
        body (the arm leaving the pose it had in the reference frame, most of its outline
        still inside the reference's region) fit a wrong correction as well as the right one.
    """

    def __init__(
        self,
        prior_pos_m: float = 0.01,
        prior_rot_deg: float = 2.0,
        pixel_sigma: float = 1.0,
        effective_points: float = 40.0,
        memory_frames: float = 10.0,
        search_px: int = 20,
        max_points: int = 300,
        huber_px: float = 1.5,
        contrast: float = 8.0,
        border_px: int = 3,
        min_points: int = 60,
        reject_px: float | None = 6.0,
    ) -> None:
        self.prior_pos_m = prior_pos_m
        self.prior_rot_deg = prior_rot_deg
        self.pixel_sigma = pixel_sigma
        self.effective_points = effective_points
        self.memory_frames = memory_frames
        self.search_px = search_px
        self.max_points = max_points
        self.huber_px = huber_px
        self.contrast = contrast
        self.border_px = border_px
        self.min_points = min_points
        self.reject_px = reject_px

    def _check_params(self) -> None:
        for name in ("prior_pos_m", "prior_rot_deg", "pixel_sigma", "effective_points", "huber_px"):
            value = getattr(self, name)
            if isinstance(value, bool) or not (np.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number, got {value!r}")
        c = self.contrast
        if isinstance(c, bool) or not (np.isfinite(c) and c >= 0):
            raise ValueError(f"contrast must be a number >= 0, got {c!r}")
        r = self.reject_px
        if r is not None and (isinstance(r, bool) or not (np.isfinite(r) and r > 0)):
            raise ValueError(f"reject_px must be a positive number or None, got {r!r}")
        m = self.memory_frames
        if isinstance(m, bool) or not (np.isfinite(m) and m >= 1):
            raise ValueError(f"memory_frames must be a number >= 1, got {m!r}")
        for name, low in (("search_px", 1), ("max_points", 6), ("border_px", 0), ("min_points", 6)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
                raise ValueError(f"{name} must be an int >= {low}, got {value!r}")

    def reset(self, camera: CameraModel) -> SilhouetteExtrinsicsFilter:
        """Start from ``camera``'s nominal calibration, with only the prior's information."""
        self._check_params()
        self.nominal_ = camera
        prior = np.r_[np.full(3, self.prior_pos_m), np.full(3, np.deg2rad(self.prior_rot_deg))]
        self.prior_information_ = np.diag(prior**-2.0)
        self.information_ = self.prior_information_.copy()
        self.information_vector_ = np.zeros(6)
        self.delta_ = np.zeros(6)
        self.n_frames_ = 0
        self.camera_ = camera
        return self

    @property
    def camera(self) -> CameraModel:
        """The camera as currently estimated (the nominal one before any update)."""
        return self.camera_

    @property
    def std(self) -> np.ndarray:
        """Posterior standard deviation of ``(v, w)`` (metres, radians)."""
        return np.sqrt(np.diag(np.linalg.inv(self.information_)))

    def update(
        self,
        predicted_mask: np.ndarray,
        predicted_depth: np.ndarray,
        foreground: np.ndarray,
        image: np.ndarray | None = None,
        unreliable: np.ndarray | None = None,
    ) -> int:
        """Take one frame: the body's ``predicted_mask`` and ``predicted_depth`` (metres along
        the optical axis) rendered with :attr:`camera`, and the observed ``foreground`` mask;
        with the camera ``image`` (RGB or grey, uint8) a foreground edge counts only where
        the image shows a step of ``contrast`` across it. Contour points whose search would
        cross ``unreliable`` pixels (e.g. where the body stood when the background was
        taken) are skipped. Returns how many points were used (0: the frame was skipped,
        fewer than ``min_points``)."""
        rows, d = self._measure(predicted_mask, predicted_depth, foreground, image, unreliable)
        if len(d) < self.min_points:
            return 0
        b = d + rows @ self.delta_  # each residual as an equation in the absolute correction
        keep = 1.0 - 1.0 / self.memory_frames  # older frames fade; the prior stays
        prior = self.prior_information_
        info = prior + keep * (self.information_ - prior)
        vector = keep * self.information_vector_
        w = np.full(len(d), self.effective_points / len(d) / self.pixel_sigma**2)
        weights = w
        for i in range(2):  # Huber reweighting against this frame's own best fit
            H = info + rows.T @ (weights[:, None] * rows)
            x = np.linalg.solve(H, vector + rows.T @ (weights * b))
            r = np.abs(b - rows @ x)
            weights = w * np.minimum(1.0, self.huber_px / np.maximum(r, 1e-9))
            if i and self.reject_px is not None:  # then Tukey's biweight: far edges are others'
                weights = weights * np.clip(1.0 - (r / self.reject_px) ** 2, 0.0, None) ** 2
        self.information_ = info + rows.T @ (weights[:, None] * rows)
        self.information_vector_ = vector + rows.T @ (weights * b)
        self.delta_ = np.linalg.solve(self.information_, self.information_vector_)
        self.camera_ = corrected(self.nominal_, self.delta_)
        self.n_frames_ += 1
        return len(d)

    def _measure(
        self,
        mask: np.ndarray,
        depth: np.ndarray,
        foreground: np.ndarray,
        image: np.ndarray | None,
        unreliable: np.ndarray | None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Rows ``n^T J`` (N x 6) and normal edge distances ``d`` (N,) of the contour points."""
        cam = self.camera_
        m = np.asarray(mask, bool)
        fg = np.asarray(foreground, bool)
        if m.shape != fg.shape or np.shape(depth) != m.shape:
            raise ValueError(
                f"predicted_mask, predicted_depth and foreground must share one shape, got "
                f"{m.shape}, {np.shape(depth)}, {fg.shape}"
            )
        h, w = m.shape
        m8 = m.astype(np.uint8)
        edge = m & ~cv2.erode(m8, np.ones((3, 3), np.uint8)).astype(bool)
        b = self.border_px
        edge[: b + 1], edge[h - b - 1 :], edge[:, : b + 1], edge[:, w - b - 1 :] = 0, 0, 0, 0
        S = int(self.search_px)
        if unreliable is not None and np.any(unreliable):
            k = 2 * S + 1
            near = cv2.dilate(np.asarray(unreliable, np.uint8), np.ones((k, k), np.uint8))
            edge &= near == 0
        ys, xs = np.nonzero(edge)
        empty = np.zeros((0, 6)), np.zeros(0)
        if len(ys) < 6:
            return empty
        if len(ys) > self.max_points:
            keep = np.linspace(0, len(ys) - 1, self.max_points).round().astype(int)
            ys, xs = ys[keep], xs[keep]
        smooth = cv2.GaussianBlur(m.astype(np.float32), (5, 5), 1.0)
        gx = cv2.Sobel(smooth, cv2.CV_32F, 1, 0, ksize=3)[ys, xs]
        gy = cv2.Sobel(smooth, cv2.CV_32F, 0, 1, ksize=3)[ys, xs]
        norm = np.hypot(gx, gy)
        ok = norm > 1e-6
        n = -np.c_[gx, gy][ok] / norm[ok, None]  # outward: the mask falls off that way
        ys, xs = ys[ok], xs[ok]
        # Observed edge along the normal: the inside-to-outside step nearest the predicted one
        # (which lies between the contour pixel, s = 0, and its outer neighbour, s = 1).
        s = np.arange(-S, S + 1)
        px = np.clip(np.rint(xs[:, None] + s * n[:, :1]).astype(int), 0, w - 1)
        py = np.clip(np.rint(ys[:, None] + s * n[:, 1:]).astype(int), 0, h - 1)
        inside = fg[py, px]
        step = inside[:, :-1] & ~inside[:, 1:]  # at s[j]: inside, s[j + 1]: outside
        if image is not None:  # the image's own step across it, from s[j - 1] to s[j + 2]
            grey = _grey(image, m.shape)[py, px]
            grey = np.pad(grey, ((0, 0), (1, 1)), mode="edge")
            step &= np.abs(grey[:, 3:] - grey[:, :-3]) >= self.contrast
        if not step.any():
            return empty
        dist = np.where(step, np.abs(s[:-1])[None, :], 10 * S)
        j = dist.argmin(axis=1)
        found = step[np.arange(len(j)), j]
        d = s[:-1][j][found].astype(float)
        ys, xs, n = ys[found], xs[found], n[found]
        z = np.asarray(depth, float)[ys, xs]
        good = np.isfinite(z) & (z > 1e-3)
        ys, xs, n, d, z = ys[good], xs[good], n[good], d[good], z[good]
        if len(d) < 6:
            return empty
        K = np.asarray(cam.K, float)
        fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
        X = np.c_[(xs - cx) / fx * z, (ys - cy) / fy * z, z]  # camera-frame points
        P = np.zeros((len(z), 2, 3))  # d(pixel)/d(camera point)
        P[:, 0, 0], P[:, 0, 2] = fx / z, -fx * X[:, 0] / z**2
        P[:, 1, 1], P[:, 1, 2] = fy / z, -fy * X[:, 1] / z**2
        # The point in the corrected camera: exp(delta)^-1 X ~ X - v + [X]x w.
        dX = np.concatenate([-np.broadcast_to(np.eye(3), (len(z), 3, 3)), _skew(X)], axis=2)
        J = P @ dX  # (N, 2, 6)
        rows = np.einsum("ni,nij->nj", n, J)
        return rows, d
