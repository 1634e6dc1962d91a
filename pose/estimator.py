"""The pose-manifold estimator: SIFT bunches -> manifold coordinates -> RBF regressor.

Pipeline of :meth:`PoseManifoldEstimator.predict` (each stage is its own module):

a. SIFT keypoints inside the mask (:mod:`pose.keypoints`);
b. outlier removal: vote for training views with a FLANN index, match the best-voted ones and
   keep the inliers of RANSAC homographies (:mod:`pose.matching`);
c. k-means bunches of the inliers (:mod:`pose.bunches`);
d. in-plane reference direction (``reference="keypoints"``): every inlier votes its SIFT
   orientation minus the canonical orientation of its nearest training descriptor (that
   descriptor's orientation relative to its view's heading,
   :func:`pose.rotations.inplane_heading`); the vote peak is the heading
   (:func:`pose.orientation.keypoint_heading`).
   ``reference="silhouette"`` is the older long-axis / saturation-centroid direction;
e. manifold coordinates: distances of the bunch vectors to the anchor bunch, plus the
   silhouette block (shape descriptor, elongation, size) and the appearance block (visual-word
   histogram of the inliers) (:mod:`pose.manifold`, :mod:`pose.vocabulary`);
f. RBF regression to the rotation expressed relative to the reference direction, in the 6-D
   representation, projected back onto SO(3) (:mod:`pose.rbf`, :mod:`pose.rotations`). The
   network is normalised, with one narrow unit per training sample: under a fixed camera the
   relative rotation is nearly constant per resting face, a target that a wide, smooth RBF
   blurs between faces. Training adds half-plane occluded copies of each view
   (``augment_occlusion``) so that occluded silhouettes and keypoint sets are seen in fit.

No stage of the coarse path uses a homography to a training view; the keypoint heading uses
only the nearest training *descriptor* of each inlier, pooled over all views.
Measured on the 640x480 top-camera benchmark (11 objects, 30 held-out poses each), coarse
success@5 deg at 0 / 25 / 50 / 75 % occlusion: 74 / 42 / 41 / 35 % with the silhouette
reference and a wide 96-unit RBF, 99 / 97 / 98 / 74 % now (refined: unchanged).

Refinement (``refine=True``): the homography to the best-matching training view, linearised at
the object centre, gives the in-plane angle between the two views; the training view's known
rotation turned by that angle about the optical axis replaces the coarse one.
``rotation_coarse`` keeps the pure manifold answer for ablation.

Rotations are camera-frame (egocentric) by default. ``allocentric=True`` learns them relative to
the viewing ray instead, the usual choice for distant objects; under the top camera, where
objects slide parallel to the image plane and most features lie on the upward face, it was
measured worse (potted_meat_can, 320x240: median 4.6 deg refined error against 0.14 deg).

Position: the object centre (the training view's mask centroid carried through the homography,
so that occlusion does not shift it) is back-projected onto the horizontal plane learned from
that training view (:func:`pose.geometry.effective_height`). ``translation_regressed`` is the
alternative from an RBF on the centre's normalised image coordinates and apparent size.
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

from pose.bunches import make_bunches
from pose.geometry import camera_point, centre_and_size, effective_height, world_point
from pose.keypoints import Features, extract_sift
from pose.manifold import manifold_coordinates
from pose.matching import (
    DescriptorIndex,
    apply_homography,
    local_similarity,
    ransac_homography,
    ratio_match,
)
from pose.orientation import elongation, hull_mask, keypoint_heading, reference_angle
from pose.rbf import RBFNetwork, ScipyRBF
from pose.rotations import from_6d, inplane_heading, ray_rotation, rot_z, to_6d
from pose.serialization import load_arrays, save_arrays
from pose.shape.descriptors import shape_descriptor
from pose.view import PoseEstimate, View
from pose.vocabulary import learn_vocabulary, word_histogram

N_SHAPE = 73 + 2  # shared descriptor + elongation + log angular size


SHAPE_SIDE = 48


def shape_features(mask: np.ndarray | None) -> np.ndarray | None:
    """The shared 73-D silhouette descriptor, or None without a usable mask.

    The silhouette is cropped and resampled to at most ``SHAPE_SIDE`` pixels a side first: the
    descriptor is scale-invariant, and its cost grows with the pixel count (about 30 ms for a
    100x100 silhouette, 5 ms at 64x64, 3.5 ms at 48x48), which would otherwise eat the whole
    time budget.
    """
    if mask is None:
        return None
    m = np.asarray(mask, np.uint8)
    x, y, w, h = cv2.boundingRect(m)
    crop = m[y : y + h, x : x + w].astype(np.float32)
    if np.count_nonzero(crop) < 16:
        return None
    scale = SHAPE_SIDE / max(crop.shape)
    if scale < 1.0:
        size = (max(1, round(crop.shape[1] * scale)), max(1, round(crop.shape[0] * scale)))
        crop = cv2.resize(crop, size, interpolation=cv2.INTER_AREA)
    crop = np.pad(crop >= 0.5, 2)
    if np.count_nonzero(crop) < 16:
        return None
    return np.asarray(shape_descriptor(crop), float).ravel()


def occlude_features(
    f: Features, mask: np.ndarray, fraction: float, rng: np.random.Generator
) -> tuple[Features, np.ndarray]:
    """Training augmentation: hide ``fraction`` of ``mask`` behind a random half-plane (as
    :func:`scorbot_gym.views.occlude` does to test views) and keep the keypoints left visible.
    Returns those keypoints and the visible mask."""
    theta = rng.uniform(0, 2 * np.pi)
    d = np.array([np.cos(theta), np.sin(theta)])
    x, y, w, h = cv2.boundingRect(np.asarray(mask, np.uint8))
    ys, xs = np.nonzero(np.asarray(mask)[y : y + h, x : x + w])
    cut = np.quantile((xs + x) * d[0] + (ys + y) * d[1], 1.0 - fraction)
    visible = np.zeros(np.shape(mask), bool)
    keep = (xs + x) * d[0] + (ys + y) * d[1] <= cut
    visible[ys[keep] + y, xs[keep] + x] = True
    return f.subset(f.xy @ d <= cut), visible


def _check_poses(poses, n: int) -> np.ndarray:
    P = np.asarray(poses, float)
    if P.shape != (n, 4, 4):
        raise ValueError(f"poses must be ({n}, 4, 4) camera_from_object matrices, got {P.shape}")
    if not np.allclose(P[:, :3, :3] @ P[:, :3, :3].transpose(0, 2, 1), np.eye(3), atol=1e-4):
        raise ValueError("poses[:, :3, :3] must be rotation matrices")
    return P


class PoseManifoldEstimator(BaseEstimator):
    """Estimate an object's pose in the camera frame from one view.

    ``fit(views, poses)`` takes :class:`~pose.view.View` objects of one object and its poses as
    ``(N, 4, 4)`` ``camera_from_object`` matrices; ``predict(view)`` returns a
    :class:`~pose.view.PoseEstimate`. ``regressor`` is ``"rbf"`` (k-means RBF network) or
    ``"scipy"`` (:class:`scipy.interpolate.RBFInterpolator`).
    """

    def __init__(
        self,
        n_bunches: int = 8,
        reference: str = "keypoints",
        regressor: str = "rbf",
        n_centers: int = 1000,
        width_scale: float = 0.1,
        ridge: float = 1e-4,
        normalized_rbf: bool = True,
        use_shape: bool = True,
        shape_weight: float = 1.0,
        n_words: int = 32,
        words_weight: float = 3.0,
        augment_occlusion: tuple[float, ...] = (0.3, 0.6),
        appearance_weight: float = 1.0,
        geometry_weight: float = 2.0,
        max_train_features: int = 200,
        contrast_threshold: float = 0.03,
        ratio: float = 0.85,
        ransac_method: str = "ransac",
        ransac_threshold: float = 4.0,
        min_inliers: int = 8,
        n_candidates: int = 4,
        refine: bool = True,
        allocentric: bool = False,
        random_state: int = 0,
    ):
        self.n_bunches = n_bunches
        self.reference = reference
        self.regressor = regressor
        self.n_centers = n_centers
        self.width_scale = width_scale
        self.ridge = ridge
        self.normalized_rbf = normalized_rbf
        self.use_shape = use_shape
        self.shape_weight = shape_weight
        self.n_words = n_words
        self.words_weight = words_weight
        self.augment_occlusion = augment_occlusion
        self.appearance_weight = appearance_weight
        self.geometry_weight = geometry_weight
        self.max_train_features = max_train_features
        self.contrast_threshold = contrast_threshold
        self.ratio = ratio
        self.ransac_method = ransac_method
        self.ransac_threshold = ransac_threshold
        self.min_inliers = min_inliers
        self.n_candidates = n_candidates
        self.refine = refine
        self.allocentric = allocentric
        self.random_state = random_state

    # ------------------------------------------------------------------ features
    def _manifold_input(
        self, image, xy, desc, centre, size, mask, focal: float = 1.0, angle: float | None = None
    ) -> tuple[np.ndarray, float]:
        """Manifold coordinates (+ silhouette block) and the in-plane reference angle (the
        silhouette's, :func:`pose.orientation.reference_angle`, unless ``angle`` is given).

        The silhouette block is the shared 73-D shape descriptor, the silhouette's elongation
        and its angular size ``log(size / focal)``: the descriptor is invariant to affine maps
        and scale, so it cannot tell a 60x45 face of a box from a 70x45 one; the last two can.
        """
        region = mask if mask is not None else hull_mask(xy, image.shape[:2])
        if angle is None:
            angle = reference_angle(image, region, centre)
        b = make_bunches(
            xy,
            desc,
            centre,
            size,
            self.n_bunches,
            self.appearance_weight,
            self.geometry_weight,
            seed=self.random_state,
        )
        coords = manifold_coordinates(b, angle)
        if not self.use_shape:
            return coords, angle
        shape = shape_features(mask)
        if shape is None:
            shape = np.full(N_SHAPE - 2, np.nan)  # replaced by the training mean (neutral)
        return np.r_[coords, shape, elongation(region), np.log(size / focal)], angle

    def _scale_inputs(self, X: np.ndarray) -> np.ndarray:
        """Standardise, then weight the shape block (and the visual-word block) so that it
        counts ``shape_weight`` (``words_weight``) times as much as the whole manifold block in
        the RBF distances, whatever its dimension. Layout: manifold, shape, words."""
        X = np.where(np.isnan(X), self.x_mean_, X)
        Z = (X - self.x_mean_) / self.x_scale_
        nb = self.n_bunches
        if self.use_shape:
            Z[:, nb : nb + N_SHAPE] *= self.shape_weight * np.sqrt(nb / N_SHAPE)
        if self.n_words:
            Z[:, -self.n_words :] *= self.words_weight * np.sqrt(nb / self.n_words)
        return Z

    def _make_regressor(self):
        if self.regressor == "rbf":
            return RBFNetwork(
                n_centers=self.n_centers,
                width_scale=self.width_scale,
                alpha=self.ridge,
                standardize=False,
                normalized=self.normalized_rbf,
                random_state=self.random_state,
            )
        if self.regressor == "scipy":
            return ScipyRBF(smoothing=self.ridge, standardize=False)
        raise ValueError(f"regressor must be 'rbf' or 'scipy', got {self.regressor!r}")

    def _validate_params(self) -> None:
        if self.n_bunches < 2:
            raise ValueError(f"n_bunches must be >= 2, got {self.n_bunches}")
        if self.min_inliers < 4:
            raise ValueError(f"min_inliers must be >= 4 (a homography), got {self.min_inliers}")
        if self.n_candidates < 1:
            raise ValueError(f"n_candidates must be >= 1, got {self.n_candidates}")
        if self.reference not in ("keypoints", "silhouette"):
            raise ValueError(
                f"reference must be 'keypoints' or 'silhouette', got {self.reference!r}"
            )
        self._make_regressor()

    # ----------------------------------------------------------------------- fit
    def fit(self, views: Sequence[View], poses) -> PoseManifoldEstimator:
        """Learn from unoccluded views of one object and their ``camera_from_object`` poses."""
        self._validate_params()
        views = list(views)
        if not views:
            raise ValueError("fit needs at least one view")
        if not all(isinstance(v, View) for v in views):
            raise ValueError("views must be pose.view.View instances")
        P = _check_poses(poses, len(views))
        X, Y, T, Xt, D = [], [], [], [], []
        rng = np.random.default_rng(self.random_state)
        db_xy, db_desc, db_view, db_phi = [], [], [], []
        R_allo, centres, sizes, z_eff, z_origin = [], [], [], [], []
        for view, pose in zip(views, P, strict=True):
            f = extract_sift(
                view.image, view.mask, self.max_train_features, self.contrast_threshold
            )
            if len(f) < max(self.n_bunches, self.min_inliers):
                continue
            centre, size = centre_and_size(view.mask, f.xy)
            K = view.camera.K
            R_a = self._ray(K, centre).T @ pose[:3, :3]
            heading = inplane_heading(R_a) if self.reference == "keypoints" else None
            x, angle = self._manifold_input(
                view.image, f.xy, f.descriptors, centre, size, view.mask, K[0, 0], heading
            )
            X.append(x)
            Y.append(to_6d(rot_z(-angle) @ R_a))
            D.append(f.descriptors)
            for frac in self.augment_occlusion if view.mask is not None else ():
                g, visible = occlude_features(f, view.mask, frac, rng)
                if len(g) < self.n_bunches:
                    continue
                xo, ao = self._manifold_input(
                    view.image, g.xy, g.descriptors, centre, size, visible, K[0, 0], heading
                )
                X.append(xo)
                Y.append(to_6d(rot_z(-ao) @ R_a))
                D.append(g.descriptors)
            Xt.append(self._translation_input(K, centre, size))
            T.append(pose[:3, 3])
            k = len(R_allo)
            db_xy.append(f.xy)
            db_desc.append(f.descriptors)
            db_view.append(np.full(len(f), k))
            db_phi.append(np.angle(np.exp(1j * (f.angles - angle))))  # relative to the heading
            R_allo.append(R_a)
            centres.append(centre)
            sizes.append(size)
            origin_w = world_point(view.camera, pose[:3, 3])
            z_eff.append(effective_height(view.camera, centre, origin_w))
            z_origin.append(origin_w[2])
        if len(X) < 2:
            raise ValueError(
                f"only {len(X)} of {len(views)} training views have at least "
                f"{max(self.n_bunches, self.min_inliers)} SIFT keypoints in the mask; "
                "check that the object is visible and textured"
            )
        X = np.array(X)
        if self.n_words:
            self.words_ = learn_vocabulary(np.concatenate(db_desc), self.n_words, self.random_state)
            X = np.c_[X, [word_histogram(d, self.words_) for d in D]]
        else:
            self.words_ = np.zeros((0, 128), np.float32)
        known = np.isfinite(X).any(axis=0)  # silhouette columns are NaN when no view has a mask
        self.x_mean_ = np.zeros(X.shape[1])
        self.x_mean_[known] = np.nanmean(X[:, known], axis=0)
        sd = np.ones(X.shape[1])
        sd[known] = np.nanstd(X[:, known], axis=0)
        self.x_scale_ = np.where(sd > 1e-12, sd, 1.0)
        self.rot_regressor_ = self._make_regressor().fit(self._scale_inputs(X), np.array(Y))
        self.trans_regressor_ = RBFNetwork(
            n_centers=min(self.n_centers, 32), alpha=self.ridge, random_state=self.random_state
        ).fit(np.array(Xt), np.array(T))
        self.db_xy_ = np.concatenate(db_xy).astype(np.float32)
        self.db_desc_ = np.concatenate(db_desc).astype(np.float32)
        self.db_view_ = np.concatenate(db_view)
        self.db_phi_ = np.concatenate(db_phi).astype(np.float32)
        self.view_R_allo_ = np.array(R_allo)
        self.view_centre_ = np.array(centres)
        self.view_size_ = np.array(sizes)
        self.view_z_eff_ = np.array(z_eff)
        self.view_z_origin_ = np.array(z_origin)
        self.n_train_views_ = len(R_allo)
        self._build_index()
        return self

    def _build_index(self) -> None:
        self._index = DescriptorIndex(
            self.db_desc_, self.db_view_, self.n_train_views_, self.random_state
        )
        self._view_start = np.searchsorted(self.db_view_, np.arange(self.n_train_views_ + 1))

    def _ray(self, K: np.ndarray, centre: np.ndarray) -> np.ndarray:
        return ray_rotation(K, centre) if self.allocentric else np.eye(3)

    @staticmethod
    def _translation_input(K: np.ndarray, centre: np.ndarray, size: float) -> np.ndarray:
        n = np.linalg.solve(K, np.r_[centre, 1.0])
        return np.r_[n[:2], size / K[0, 0]]

    # ------------------------------------------------------------------- predict
    def _match(self, f: Features, neighbours: tuple[np.ndarray, np.ndarray]):
        """Best training views by votes, each with its RANSAC homography and inliers."""
        votes = self._index.vote(f.descriptors, neighbours=neighbours)
        order = np.argsort(-votes, kind="stable")[: self.n_candidates]
        results = []
        for v in order[votes[order] > 0]:
            a, b = self._view_start[v], self._view_start[v + 1]
            pairs = ratio_match(f.descriptors, self.db_desc_[a:b], self.ratio)
            if len(pairs) < self.min_inliers:
                continue
            H, inl = ransac_homography(
                self.db_xy_[a:b][pairs[:, 1]],
                f.xy[pairs[:, 0]],
                self.ransac_method,
                self.ransac_threshold,
                self.random_state,
            )
            if H is not None and inl.sum() >= self.min_inliers:
                results.append((int(v), H, pairs[inl, 0]))
        return results

    def predict(self, view: View) -> PoseEstimate:
        """Pose of the object in ``view``; ``valid=False`` (never an exception) when the view
        has too few keypoints or none consistent with a training view."""
        check_is_fitted(self, "rot_regressor_")
        if not isinstance(view, View):
            raise ValueError(f"predict expects a pose.view.View, got {type(view).__name__}")
        tm: dict[str, float] = {}
        t0 = tic = time.perf_counter()

        def lap(name: str) -> None:
            nonlocal tic
            now = time.perf_counter()
            tm[name] = (now - tic) * 1e3
            tic = now

        f = extract_sift(view.image, view.mask, 0, self.contrast_threshold)
        lap("sift")
        if len(f) < max(self.n_bunches, self.min_inliers):
            tm["total"] = (time.perf_counter() - t0) * 1e3
            return PoseEstimate.invalid(f"only {len(f)} keypoints", tm, len(f))
        neighbours = self._index.nearest(f.descriptors)
        matches = self._match(f, neighbours)
        lap("match")
        if not matches:
            tm["total"] = (time.perf_counter() - t0) * 1e3
            return PoseEstimate.invalid("no training view matches geometrically", tm, len(f))
        best, H, best_inl = max(matches, key=lambda m: len(m[2]))
        kept = np.unique(np.concatenate([m[2] for m in matches]))
        centre = apply_homography(H, self.view_centre_[best])[0]
        angle_h, scale_h = local_similarity(H, self.view_centre_[best])
        size = self.view_size_[best] * scale_h
        if not (0.5 < scale_h < 2.0 and np.isfinite(centre).all()):  # degenerate homography
            centre, size = centre_and_size(view.mask, f.xy[kept])
        pts = f.subset(kept) if len(kept) >= 2 * self.n_bunches else f
        heading = None
        if self.reference == "keypoints":
            nn = neighbours[0][kept, 0]
            heading, _ = keypoint_heading(f.angles[kept][nn >= 0], self.db_phi_[nn[nn >= 0]])
        K = view.camera.K
        x, angle = self._manifold_input(
            view.image, pts.xy, pts.descriptors, centre, size, view.mask, K[0, 0], heading
        )
        lap("manifold")
        R_ray = self._ray(K, centre)
        if self.n_words:
            x = np.r_[x, word_histogram(pts.descriptors, self.words_)]
        y = self.rot_regressor_.predict(self._scale_inputs(x[None]))[0]
        R_coarse = R_ray @ rot_z(angle) @ from_6d(y)
        t_reg = self.trans_regressor_.predict(self._translation_input(K, centre, size)[None])[0]
        lap("regress")
        R_refined = R_ray @ rot_z(angle_h) @ self.view_R_allo_[best]
        try:
            ground = view.camera.backproject_to_plane(centre[None], self.view_z_eff_[best])[0]
            ground[2] = self.view_z_origin_[best]
            t_geo = camera_point(view.camera, ground)
        except ValueError:  # viewing ray parallel to the table: only the regressed one is left
            t_geo = t_reg
        lap("refine")
        tm["total"] = (time.perf_counter() - t0) * 1e3
        n_inl = len(best_inl)
        # Fraction of keypoints explained, discounted when the inlier count itself is small.
        conf = (len(kept) / len(f)) * min(1.0, n_inl / (3.0 * self.min_inliers))
        return PoseEstimate(
            rotation=R_refined if self.refine else R_coarse,
            translation=t_geo,
            confidence=float(conf),
            valid=True,
            timings_ms=tm,
            rotation_coarse=R_coarse,
            translation_regressed=t_reg,
            n_keypoints=len(f),
            n_inliers=n_inl,
        )

    # ------------------------------------------------------------------ save/load
    _FITTED = (
        "x_mean_",
        "x_scale_",
        "db_xy_",
        "db_desc_",
        "db_view_",
        "db_phi_",
        "words_",
        "view_R_allo_",
        "view_centre_",
        "view_size_",
        "view_z_eff_",
        "view_z_origin_",
    )

    def to_arrays(self, prefix: str = "") -> dict[str, np.ndarray]:
        check_is_fitted(self, "rot_regressor_")
        out = {prefix + "params": np.array(json.dumps(self.get_params()))}
        for k in self._FITTED:
            v = getattr(self, k)
            out[prefix + k] = v.astype(np.float16) if k == "db_desc_" else v
        for k, v in self.rot_regressor_.to_arrays().items():
            out[f"{prefix}rot/{k}"] = v
        for k, v in self.trans_regressor_.to_arrays().items():
            out[f"{prefix}trans/{k}"] = v
        return out

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], prefix: str = "") -> PoseManifoldEstimator:
        try:
            params = json.loads(str(arrays[prefix + "params"]))
            params["augment_occlusion"] = tuple(params.get("augment_occlusion", ()))  # JSON list
            est = cls(**params)
            for k in cls._FITTED:
                setattr(est, k, np.asarray(arrays[prefix + k]))
            est.db_desc_ = est.db_desc_.astype(np.float32)
            est.words_ = est.words_.astype(np.float32)
            est.db_xy_ = est.db_xy_.astype(np.float32)

            def sub(p):
                return {k[len(p) :]: v for k, v in arrays.items() if k.startswith(p)}

            est.rot_regressor_ = est._make_regressor().load_arrays(sub(prefix + "rot/"))
            est.trans_regressor_ = RBFNetwork().load_arrays(sub(prefix + "trans/"))
        except (KeyError, TypeError, json.JSONDecodeError) as exc:
            raise ValueError(f"model file is missing or has bad entries ({exc})") from exc
        est.n_train_views_ = len(est.view_R_allo_)
        est._build_index()
        return est

    def save(self, path: str | os.PathLike) -> None:
        """Write the fitted estimator to one ``.npz`` file (atomic, pickle-free, versioned)."""
        save_arrays(path, self.to_arrays(), {"kind": "estimator"})

    @classmethod
    def load(cls, path: str | os.PathLike) -> PoseManifoldEstimator:
        header, arrays = load_arrays(path)
        if header.get("kind") != "estimator":
            raise ValueError(f"{path} holds a {header.get('kind')!r}, not a single estimator")
        return cls.from_arrays(arrays)
