"""What every baseline shares: input checks, the object region, translation, timing, files.

The baselines differ in how they find the rotation; the rest is common so that a comparison
between them measures that one difference:

- :func:`check_training_set` validates ``fit(views, poses)`` as the manifold estimator does;
- :func:`object_region` and :func:`featureless` decide whether a view shows an object at all:
  an empty mask, or a flat image under the mask, makes an appearance baseline's ``predict``
  return ``valid=False`` (a keypoint baseline's answer is invalid without enough keypoints);
- :class:`BaselineEstimator` gives the position from the mask centroid ray and a reference
  training view: the manifold estimator's own geometric position (the ray through the centroid
  cut with the horizontal plane that training view implies), so that no baseline is penalised
  or favoured by a different position method. It also supplies pickle-free
  ``to_arrays``/``from_arrays``/``save``/``load`` from a list of fitted array attributes;
- :func:`appearance_patch` is the normalised, mask-cropped image the appearance baselines
  (PCA, least squares, part-based) describe.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Sequence

import cv2
import numpy as np
from sklearn.base import BaseEstimator
from sklearn.utils.validation import check_is_fitted

from pose.camera import CameraModel
from pose.features.keypoints import to_gray
from pose.geometry import (  # noqa: F401  (MIN_MASK_PIXELS, lift_to_object, pnp: re-exported)
    MIN_MASK_PIXELS,
    camera_point,
    centre_and_size,
    effective_height,
    lift_to_object,
    object_region,
    pnp,
    world_point,
)
from pose.metrics import ScoredEstimator
from pose.rotations import geodesic_deg
from pose.serialization import load_estimator_arrays, save_arrays
from pose.view import PoseEstimate, View, predict_each


def check_training_set(views: Sequence[View], poses) -> tuple[list[View], np.ndarray]:
    """The views as a list and the poses as ``(N, 4, 4)`` rotations-with-translations."""
    views = list(views)
    if not views:
        raise ValueError("fit needs at least one view")
    if not all(isinstance(v, View) for v in views):
        raise ValueError("views must be pose.view.View instances")
    P = np.asarray(poses, float)
    if P.shape != (len(views), 4, 4):
        raise ValueError(
            f"poses must be ({len(views)}, 4, 4) camera_from_object matrices, got {P.shape}"
        )
    if not np.allclose(P[:, :3, :3] @ P[:, :3, :3].transpose(0, 2, 1), np.eye(3), atol=1e-4):
        raise ValueError("poses[:, :3, :3] must be rotation matrices")
    return views, P


def check_view(view: View) -> None:
    if not isinstance(view, View):
        raise ValueError(f"predict expects a pose.view.View, got {type(view).__name__}")


def featureless(view: View, region: np.ndarray) -> bool:
    """True when the image is flat inside ``region`` (a blank frame under a mask): nothing for
    an appearance method to describe, even though the mask says "object"."""
    return float(to_gray(view.image)[region].std()) < 1.0


def require_masks(views: Sequence[View], who: str) -> None:
    """Appearance baselines crop by the mask: training views without one are an input error."""
    bad = [i for i, v in enumerate(views) if object_region(v) is None]
    if bad:
        raise ValueError(
            f"{who} needs a mask with at least {MIN_MASK_PIXELS} pixels in every training view; "
            f"views {bad[:5]} have none"
        )


def nearest_rotation(R: np.ndarray, rotations: np.ndarray) -> int:
    """Index of the training rotation closest (geodesic) to ``R``."""
    return int(np.argmin(geodesic_deg(rotations, np.asarray(R)[None])))


class Timer:
    """Named laps in milliseconds, ending with ``total``: ``PoseEstimate.timings_ms``."""

    def __init__(self) -> None:
        self.ms: dict[str, float] = {}
        self._t0 = self._tic = time.perf_counter()

    def lap(self, name: str) -> None:
        now = time.perf_counter()
        self.ms[name] = (now - self._tic) * 1e3
        self._tic = now

    def done(self) -> dict[str, float]:
        self.ms["total"] = (time.perf_counter() - self._t0) * 1e3
        return self.ms


class BaselineEstimator(ScoredEstimator, BaseEstimator):
    """Shared position method, contract and file format (the params as JSON plus the
    ``_FITTED`` arrays).

    Subclasses implement ``_predict_one(view)``; ``predict`` takes one view or a sequence of
    them (a list of answers), as the manifold estimator's does, and ``score`` rates a set.
    They set ``_FITTED`` (array attributes set by ``fit``, ending with ``TRANSLATION``), call
    :meth:`_fit_translation` in ``fit`` and may override :meth:`_after_load` to rebuild derived
    state (an index) from the arrays.
    """

    _FITTED: tuple[str, ...] = ()
    #: attributes holding fitted models with ``to_arrays``/``load_arrays`` (an RBF network);
    #: :meth:`_new_submodel` makes the empty one that loading fills
    _SUBMODELS: tuple[str, ...] = ()
    TRANSLATION = (
        "tr_rotation_",
        "tr_centre_",
        "tr_size_",
        "tr_z_eff_",
        "tr_z_origin_",
        "tr_depth_",
    )

    def predict(self, view: View | Sequence[View]) -> PoseEstimate | list[PoseEstimate]:
        """The estimate for one view, or a list of them for a sequence of views."""
        return predict_each(self._predict_one, view)

    def _predict_one(self, view: View) -> PoseEstimate:
        raise NotImplementedError

    def _fit_translation(self, views: Sequence[View], poses: np.ndarray) -> None:
        """Per training view: its rotation, mask centroid and size, the height of the point on
        the centroid's ray above the object origin (:func:`pose.geometry.effective_height`),
        the origin's table height and its depth."""
        centres, sizes, z_eff, z_origin = [], [], [], []
        for view, pose in zip(views, poses, strict=True):
            region = object_region(view)
            if region is None:  # keypoint baselines accept mask-less views: the image centre
                c, s = np.array([view.camera.width, view.camera.height]) / 2.0, 1.0
            else:
                c, s = centre_and_size(region, np.zeros((1, 2)))
            origin_w = world_point(view.camera, pose[:3, 3])
            centres.append(c)
            sizes.append(s)
            z_eff.append(effective_height(view.camera, c, origin_w))
            z_origin.append(origin_w[2])
        self.tr_rotation_ = poses[:, :3, :3].copy()
        self.tr_centre_ = np.array(centres)
        self.tr_size_ = np.array(sizes)
        self.tr_z_eff_ = np.array(z_eff)
        self.tr_z_origin_ = np.array(z_origin)
        self.tr_depth_ = poses[:, 2, 3].copy()

    def _translation(self, camera: CameraModel, centre: np.ndarray, size: float, ref: int):
        """Where the ray through ``centre`` meets the height that training view ``ref``
        implies; a ray parallel to the table falls back to ``ref``'s depth scaled by size."""
        try:
            ground = camera.backproject_to_plane(np.asarray(centre)[None], self.tr_z_eff_[ref])[0]
            ground[2] = self.tr_z_origin_[ref]
            return camera_point(camera, ground)
        except ValueError:
            z = self.tr_depth_[ref] * self.tr_size_[ref] / max(size, 1e-9)
            return np.linalg.solve(camera.K, np.r_[centre, 1.0]) * z

    def to_arrays(self, prefix: str = "") -> dict[str, np.ndarray]:
        check_is_fitted(self, self._FITTED[0])
        out = {prefix + "params": np.array(json.dumps(self.get_params()))}
        for k in self._FITTED:
            out[prefix + k] = np.asarray(getattr(self, k))
        for name in self._SUBMODELS:
            for k, v in getattr(self, name).to_arrays().items():
                out[f"{prefix}{name}/{k}"] = v
        return out

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], prefix: str = ""):
        try:
            params = json.loads(str(arrays[prefix + "params"]))
            est = cls(**params)
            for k in cls._FITTED:
                setattr(est, k, np.asarray(arrays[prefix + k]))
            for name in est._SUBMODELS:
                p = f"{prefix}{name}/"
                sub = {k[len(p) :]: v for k, v in arrays.items() if k.startswith(p)}
                setattr(est, name, est._new_submodel(name).load_arrays(sub))
        except (KeyError, TypeError, json.JSONDecodeError) as exc:
            raise ValueError(f"model file is missing or has bad entries ({exc})") from exc
        est._after_load()
        return est

    def _new_submodel(self, name: str):
        raise NotImplementedError(f"{type(self).__name__} has no submodel {name!r}")

    def _after_load(self) -> None:
        """Rebuild state derived from the fitted arrays (nothing by default)."""

    def save(self, path: str | os.PathLike) -> None:
        """Write the fitted estimator to one ``.npz`` file (atomic, pickle-free, versioned)."""
        meta = {"kind": "estimator", "class": type(self).__name__}
        save_arrays(path, self.to_arrays(), meta)

    @classmethod
    def load(cls, path: str | os.PathLike):
        header, arrays = load_estimator_arrays(path, cls.__name__)
        return cls.from_arrays(arrays)


def invalid(reason: str, timer: Timer, n_keypoints: int = 0) -> PoseEstimate:
    return PoseEstimate.invalid(reason, timer.done(), n_keypoints)


def appearance_input(view: View) -> tuple[Timer, np.ndarray | None, PoseEstimate | None]:
    """The start of an appearance baseline's ``predict``: a started timer, the object region,
    and the invalid answer to return instead when there is nothing to describe (no usable
    mask, or a flat image under it)."""
    check_view(view)
    timer = Timer()
    region = object_region(view)
    if region is None:
        return timer, None, invalid("no object mask", timer)
    if featureless(view, region):
        return timer, None, invalid("the object region is featureless", timer)
    return timer, region, None


def appearance_patch(image: np.ndarray, region: np.ndarray, side: int) -> np.ndarray:
    """Grey image of the object, cropped to the square around its mask's bounding box, resized
    to ``side x side``, zero mean and unit norm over the object, 0 outside the mask.

    Scale and position are normalised by the visible mask (what an appearance method sees);
    an occluder shrinks that box, which is one of the things these baselines do not handle.
    """
    gray = to_gray(image).astype(np.float32)
    x, y, w, h = cv2.boundingRect(region.astype(np.uint8))
    half = max(w, h) / 2.0
    cx, cy = x + w / 2.0, y + h / 2.0
    # Affine crop: the square [cx-half, cx+half] x [cy-half, cy+half] onto [0, side].
    s = side / (2.0 * half)
    if s < 1.0:  # anti-alias before shrinking
        gray = cv2.GaussianBlur(gray, (0, 0), 0.5 / s)
    A = np.array([[s, 0.0, side / 2.0 - s * cx], [0.0, s, side / 2.0 - s * cy]], np.float32)
    g = cv2.warpAffine(gray, A, (side, side), flags=cv2.INTER_LINEAR)
    m = cv2.warpAffine(region.astype(np.float32), A, (side, side)) > 0.5
    if not m.any():
        return np.zeros(side * side, np.float32)
    g = np.where(m, g - g[m].mean(), 0.0)
    return (g / max(float(np.linalg.norm(g)), 1e-6)).ravel().astype(np.float32)
