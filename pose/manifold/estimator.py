"""The pose-manifold estimator, composed of stage objects.

:class:`PoseManifoldEstimator` runs, for one view of one object:

a. ``keypoints`` (:class:`~pose.features.keypoints.SiftKeypoints`): SIFT inside the mask;
b. ``matcher`` (:class:`~pose.features.matching.RansacMatcher`): vote for training views with a
   FLANN index, match the best-voted ones and keep the inliers of RANSAC homographies;
c. ``bunches`` (:class:`~pose.manifold.bunches.KMeansBunches`): k-means bunches of the inliers;
d. ``reference`` (:class:`~pose.manifold.reference.KeypointHeading` or
   :class:`~pose.manifold.reference.SilhouetteDirection`): the in-plane reference direction;
e. ``featurizer`` (:class:`~pose.manifold.featurizer.ManifoldFeaturizer`): named feature blocks
   (bunch distances to the anchor, silhouette, visual words), standardised and weighted;
f. ``regressor`` (any scikit-learn regressor; :func:`default_regressor` by default): manifold
   vector -> rotation relative to the reference direction, in the 6-D representation, projected
   back onto SO(3). The default RBF network is normalised, with one narrow unit per training
   sample: under a fixed camera the relative rotation is nearly constant per resting face, a
   target that a wide, smooth RBF blurs between faces. Training adds half-plane occluded copies
   of each view (``augment_occlusion``) so that partial silhouettes and keypoint sets are seen;
g. ``refiner`` (:class:`~pose.manifold.refinement.HomographyRefiner`, or ``None`` for the pure
   manifold answer, always kept in ``PoseEstimate.rotation_coarse``).

Every stage is a constructor parameter, so an ablation is a swap
(``set_params(regressor=NearestNeighbourRegressor())``, ``refiner=None``) and
``get_params(deep=True)`` exposes the stages' own parameters (``bunches__n_bunches``) to
``GridSearchCV``. ``random_state`` seeds every stage that draws random numbers (k-means,
RANSAC, FLANN, the vocabulary, and regressors whose own ``random_state`` is ``None``).

Rotations are camera-frame (egocentric) by default; ``allocentric=True`` learns them relative to
the viewing ray instead. Position: the object centre (the training view's mask centroid carried
through the homography, so that occlusion does not shift it) is back-projected onto the
horizontal plane learnt from that training view (:func:`pose.geometry.effective_height`);
``translation_regressed`` is the alternative from ``translation_regressor`` on the centre's
normalised image coordinates and apparent size.
"""

from __future__ import annotations

import os
import time
from collections.abc import Sequence

import numpy as np
from sklearn.base import BaseEstimator, clone
from sklearn.utils.validation import check_is_fitted

from pose.features.keypoints import Features, SiftKeypoints
from pose.features.matching import RansacMatcher, apply_homography, local_similarity
from pose.geometry import (
    camera_point,
    centre_and_size,
    effective_height,
    lift_to_object,
    world_point,
)
from pose.manifold.augment import occlude_features
from pose.manifold.bunches import KMeansBunches
from pose.manifold.featurizer import ManifoldFeaturizer
from pose.manifold.reference import KeypointHeading
from pose.manifold.refinement import HomographyRefiner, RefinementInput
from pose.manifold.regressors import RBFNetwork
from pose.metrics import ScoredEstimator
from pose.orientation import hull_mask
from pose.rotations import from_6d, ray_rotation, rot_z, to_6d
from pose.view import PoseEstimate, View, predict_each


def default_regressor() -> RBFNetwork:
    """The rotation regressor: a normalised RBF network with one narrow unit per sample (up to
    1000), on inputs the featurizer has already standardised."""
    return RBFNetwork(
        n_centers=1000, width_scale=0.1, alpha=1e-4, standardize=False, normalized=True,
        random_state=None,
    )  # fmt: skip


DEFAULT_REFINER = HomographyRefiner()  # has no parameters, so sharing it is safe


def default_translation_regressor() -> RBFNetwork:
    return RBFNetwork(n_centers=32, alpha=1e-4, random_state=None)


def _check_poses(poses, n: int) -> np.ndarray:
    P = np.asarray(poses, float)
    if P.shape != (n, 4, 4):
        raise ValueError(f"poses must be ({n}, 4, 4) camera_from_object matrices, got {P.shape}")
    if not np.allclose(P[:, :3, :3] @ P[:, :3, :3].transpose(0, 2, 1), np.eye(3), atol=1e-4):
        raise ValueError("poses[:, :3, :3] must be rotation matrices")
    return P


def _seeded(estimator, seed: int):
    """A fresh copy of ``estimator``, seeded by ``seed`` where its own ``random_state`` is None."""
    est = clone(estimator)
    if "random_state" in est.get_params(deep=False) and est.random_state is None:
        est.set_params(random_state=seed)
    return est


def _lifted(view: View, xy: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Object-frame 3-D point of every keypoint ``(N, 3)``, NaN where the depth is unknown."""
    pts, ok = lift_to_object(view, np.asarray(xy, float), pose)
    out = np.full((len(xy), 3), np.nan)
    out[ok] = pts
    return out


class PoseManifoldEstimator(ScoredEstimator, BaseEstimator):
    """Estimate an object's pose in the camera frame from one view.

    ``fit(views, poses)`` takes :class:`~pose.view.View` objects of one object and its poses as
    ``(N, 4, 4)`` ``camera_from_object`` matrices; ``predict(view)`` returns a
    :class:`~pose.view.PoseEstimate` and ``predict(views)`` a list of them; ``score(views,
    poses)`` is the success@5deg fraction. A stage left as ``None`` gets its default object (a
    new one per estimator, so ``set_params(bunches__n_bunches=6)`` never changes another
    estimator's stage); ``refiner=None`` means no refinement.
    """

    def __init__(
        self,
        keypoints: SiftKeypoints | None = None,
        matcher: RansacMatcher | None = None,
        bunches: KMeansBunches | None = None,
        reference: KeypointHeading | None = None,
        featurizer: ManifoldFeaturizer | None = None,
        regressor: BaseEstimator | None = None,
        refiner: HomographyRefiner | None = DEFAULT_REFINER,
        translation_regressor: BaseEstimator | None = None,
        augment_occlusion: tuple[float, ...] = (0.3, 0.6),
        allocentric: bool = False,
        random_state: int = 0,
    ):
        self.keypoints = SiftKeypoints() if keypoints is None else keypoints
        self.matcher = RansacMatcher() if matcher is None else matcher
        self.bunches = KMeansBunches() if bunches is None else bunches
        self.reference = KeypointHeading() if reference is None else reference
        self.featurizer = ManifoldFeaturizer() if featurizer is None else featurizer
        self.regressor = default_regressor() if regressor is None else regressor
        self.refiner = refiner
        self.translation_regressor = (
            default_translation_regressor()
            if translation_regressor is None
            else translation_regressor
        )
        self.augment_occlusion = augment_occlusion
        self.allocentric = allocentric
        self.random_state = random_state

    # ------------------------------------------------------------------ helpers
    def _validate_params(self) -> None:
        for name in ("keypoints", "matcher", "bunches", "reference", "featurizer", "refiner"):
            stage = getattr(self, name)
            if stage is None and name != "refiner":
                raise ValueError(f"{name} must be a stage object, got None")
            if stage is not None and not callable(getattr(stage, "validate", None)):
                raise ValueError(f"{name} must be a stage object with validate(), got {stage!r}")
            if stage is not None:
                stage.validate()
        for name in ("regressor", "translation_regressor"):
            reg = getattr(self, name)
            if not (hasattr(reg, "fit") and hasattr(reg, "predict")):
                raise ValueError(f"{name} must be a regressor with fit/predict, got {reg!r}")
        if any(not 0 < f < 1 for f in self.augment_occlusion):
            raise ValueError(
                f"augment_occlusion fractions must be in (0, 1), got {self.augment_occlusion}"
            )

    def _min_keypoints(self, featurizer: ManifoldFeaturizer) -> int:
        n = self.bunches.n_bunches if featurizer.uses_bunches else 0
        return max(n, self.matcher.min_inliers)

    def _ray(self, K: np.ndarray, centre: np.ndarray) -> np.ndarray:
        return ray_rotation(K, centre) if self.allocentric else np.eye(3)

    @staticmethod
    def _translation_input(K: np.ndarray, centre: np.ndarray, size: float) -> np.ndarray:
        n = np.linalg.solve(K, np.r_[centre, 1.0])
        return np.r_[n[:2], size / K[0, 0]]

    def _row(self, featurizer, image, pts: Features, centre, size, mask, focal, angle):
        """The learning-free feature blocks of one view (bunches only when a block uses them);
        ``featurizer`` is the parameter in ``fit`` and its fitted copy in ``predict``."""
        region = mask if mask is not None else hull_mask(pts.xy, image.shape[:2])
        b = None
        if featurizer.uses_bunches:
            b = self.bunches.build(pts.xy, pts.descriptors, centre, size, self.random_state)
        return featurizer.row(b, angle, mask, region, size, focal)

    def _angle(self, image, pts: Features, mask, centre, R_rel) -> float:
        region = mask if mask is not None else hull_mask(pts.xy, image.shape[:2])
        return self.reference.training_angle(image, region, centre, R_rel)

    # ---------------------------------------------------------------------- fit
    def fit(self, views: Sequence[View], poses) -> PoseManifoldEstimator:
        """Learn from unoccluded views of one object and their ``camera_from_object`` poses."""
        self._validate_params()
        views = list(views)
        if not views:
            raise ValueError("fit needs at least one view")
        if not all(isinstance(v, View) for v in views):
            raise ValueError("views must be pose.view.View instances")
        P = _check_poses(poses, len(views))
        rows, Y, D, T, Xt = [], [], [], [], []
        rng = np.random.default_rng(self.random_state)
        db_xy, db_desc, db_view, db_phi, db_xyz = [], [], [], [], []
        needs_depth = bool(getattr(self.refiner, "needs_depth", False))
        if needs_depth and any(v.depth is None for v in views):
            raise ValueError(
                f"{type(self.refiner).__name__} needs View.depth in every training view "
                "(render_views(..., depth=True)) to lift the keypoints to 3-D"
            )
        R_allo, centres, sizes, z_eff, z_origin = [], [], [], [], []
        for view, pose in zip(views, P, strict=True):
            f = self.keypoints.extract(view.image, view.mask, training=True)
            if len(f) < self._min_keypoints(self.featurizer):
                continue
            centre, size = centre_and_size(view.mask, f.xy)
            K = view.camera.K
            R_a = self._ray(K, centre).T @ pose[:3, :3]
            angle = self._angle(view.image, f, view.mask, centre, R_a)
            rows.append(
                self._row(self.featurizer, view.image, f, centre, size, view.mask, K[0, 0], angle)
            )
            Y.append(to_6d(rot_z(-angle) @ R_a))
            D.append(f.descriptors)
            for frac in self.augment_occlusion if view.mask is not None else ():
                g, visible = occlude_features(f, view.mask, frac, rng)
                if len(g) < self.bunches.n_bunches:
                    continue
                ao = self._angle(view.image, g, visible, centre, R_a)
                rows.append(
                    self._row(self.featurizer, view.image, g, centre, size, visible, K[0, 0], ao)
                )
                Y.append(to_6d(rot_z(-ao) @ R_a))
                D.append(g.descriptors)
            Xt.append(self._translation_input(K, centre, size))
            T.append(pose[:3, 3])
            db_xy.append(f.xy)
            db_desc.append(f.descriptors)
            db_view.append(np.full(len(f), len(R_allo)))
            db_phi.append(np.angle(np.exp(1j * (f.angles - angle))))  # relative to the heading
            if needs_depth:
                db_xyz.append(_lifted(view, f.xy, pose))
            R_allo.append(R_a)
            centres.append(centre)
            sizes.append(size)
            origin_w = world_point(view.camera, pose[:3, 3])
            z_eff.append(effective_height(view.camera, centre, origin_w))
            z_origin.append(origin_w[2])
        if len(rows) < 2:
            raise ValueError(
                f"only {len(rows)} of {len(views)} training views have at least "
                f"{self._min_keypoints(self.featurizer)} SIFT keypoints in the mask; "
                "check that the object is visible and textured"
            )
        self.featurizer_ = clone(self.featurizer).fit(
            rows, D, np.concatenate(db_desc), self.random_state
        )
        Z = self.featurizer_.transform(np.array(rows), D)
        self.regressor_ = _seeded(self.regressor, self.random_state).fit(Z, np.array(Y))
        self.translation_regressor_ = _seeded(self.translation_regressor, self.random_state).fit(
            np.array(Xt), np.array(T)
        )
        self.db_xy_ = np.concatenate(db_xy).astype(np.float32)
        self.db_desc_ = np.concatenate(db_desc).astype(np.float32)
        self.db_view_ = np.concatenate(db_view)
        self.db_phi_ = np.concatenate(db_phi).astype(np.float32)
        self.view_R_allo_ = np.array(R_allo)
        self.view_centre_ = np.array(centres)
        self.view_size_ = np.array(sizes)
        self.view_z_eff_ = np.array(z_eff)
        self.view_z_origin_ = np.array(z_origin)
        if needs_depth:
            self.db_xyz_ = np.concatenate(db_xyz).astype(np.float32)
        elif hasattr(self, "db_xyz_"):
            del self.db_xyz_
        self.n_train_views_ = len(R_allo)
        self.n_features_in_ = Z.shape[1]
        self._build_index()
        return self

    def _build_index(self) -> None:
        self._index = self.matcher.build_index(
            self.db_desc_, self.db_view_, self.n_train_views_, self.random_state
        )
        self._view_start = np.searchsorted(self.db_view_, np.arange(self.n_train_views_ + 1))

    def __getstate__(self) -> dict:
        """Picklable (joblib, deepcopy): the FLANN index is rebuilt from the arrays instead."""
        state = self.__dict__.copy()
        state.pop("_index", None)
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        if "db_desc_" in state:
            self._build_index()

    # ------------------------------------------------------------------ predict
    def predict(self, view: View | Sequence[View]) -> PoseEstimate | list[PoseEstimate]:
        """Pose of the object in ``view`` (a list for a sequence of views); ``valid=False``
        (never an exception) when a view has too few keypoints, none consistent with a training
        view, or the stages give a non-finite pose."""
        check_is_fitted(self, "regressor_")
        return predict_each(self._predict_one, view)

    def explained_keypoints(self, view: View) -> np.ndarray:
        """Pixel positions ``(K, 2)`` of the view's keypoints that this model explains: the
        inliers of the RANSAC homographies from its training views (stages a and b of
        :meth:`predict`, without the pose). Where several objects share a mask, each object's
        model explains its own keypoints, which is what splitting the mask between them needs
        (:class:`pose.splitting.KeypointWatershedSplitter`). Empty when too few keypoints or
        no training view matches."""
        check_is_fitted(self, "regressor_")
        f = self.keypoints.extract(view.image, view.mask)
        if len(f) < self.matcher.min_inliers:
            return np.zeros((0, 2), np.float32)
        neighbours = self._index.nearest(f.descriptors)
        matches = self.matcher.match(
            f.descriptors, f.xy, self._index, neighbours, self.db_xy_, self._view_start,
            self.random_state,
        )  # fmt: skip
        if not matches:
            return np.zeros((0, 2), np.float32)
        return f.xy[np.unique(np.concatenate([m.inliers for m in matches]))]

    def _predict_one(self, view: View) -> PoseEstimate:
        tm: dict[str, float] = {}
        t0 = tic = time.perf_counter()

        def lap(name: str) -> None:
            nonlocal tic
            now = time.perf_counter()
            tm[name] = (now - tic) * 1e3
            tic = now

        def invalid(reason: str, n: int) -> PoseEstimate:
            tm["total"] = (time.perf_counter() - t0) * 1e3
            return PoseEstimate.invalid(reason, tm, n)

        f = self.keypoints.extract(view.image, view.mask)
        lap("sift")
        if len(f) < self._min_keypoints(self.featurizer_):
            return invalid(f"only {len(f)} keypoints", len(f))
        neighbours = self._index.nearest(f.descriptors)
        matches = self.matcher.match(
            f.descriptors, f.xy, self._index, neighbours, self.db_xy_, self._view_start,
            self.random_state,
        )  # fmt: skip
        lap("match")
        if not matches:
            return invalid("no training view matches geometrically", len(f))
        best, H, best_inl, _, _ = max(matches, key=lambda m: len(m.inliers))
        kept = np.unique(np.concatenate([m.inliers for m in matches]))
        centre = apply_homography(H, self.view_centre_[best])[0]
        angle_h, scale_h = local_similarity(H, self.view_centre_[best])
        size = self.view_size_[best] * scale_h
        if not (0.5 < scale_h < 2.0 and np.isfinite(centre).all()):  # degenerate homography
            centre, size = centre_and_size(view.mask, f.xy[kept])
        pts = f.subset(kept) if len(kept) >= 2 * self.bunches.n_bunches else f
        nn = neighbours[0][kept, 0]
        region = view.mask if view.mask is not None else hull_mask(pts.xy, view.image.shape[:2])
        angle = self.reference.query_angle(
            view.image, region, centre, f.angles[kept][nn >= 0], self.db_phi_[nn[nn >= 0]]
        )
        K = view.camera.K
        row = self._row(self.featurizer_, view.image, pts, centre, size, view.mask, K[0, 0], angle)
        lap("manifold")
        R_ray = self._ray(K, centre)
        y = self.regressor_.predict(self.featurizer_.transform(row[None], [pts.descriptors]))[0]
        if not (np.isfinite(y).all() and np.isfinite(angle)):
            return invalid("the stages gave a non-finite pose (corrupt model?)", len(f))
        R_coarse = R_ray @ rot_z(angle) @ from_6d(y)
        t_in = self._translation_input(K, centre, size)[None]
        t_reg = self.translation_regressor_.predict(t_in)[0]
        lap("regress")
        R, t_solved = R_coarse, None
        if self.refiner is not None:
            pairs, n_inl = np.zeros((0, 2), np.int64), 0
            if getattr(self.refiner, "needs_depth", False):  # only 3-D refiners read matches
                inl = np.concatenate([np.c_[m.inliers, m.db_rows] for m in matches])
                pairs = np.concatenate([inl] + [m.pairs for m in matches])
                _, first = np.unique(pairs[:, 0], return_index=True)
                pairs = pairs[np.sort(first)]  # each query keypoint once, inliers first
                n_inl = len(np.unique(inl[:, 0]))
            inp = RefinementInput(
                R_coarse, R_ray, angle_h, self.view_R_allo_[best], f.xy[pairs[:, 0]].astype(float),
                pairs[:, 1], getattr(self, "db_xyz_", None), view.camera, self.random_state,
                n_inliers=n_inl, keypoints_xy=f.xy, neighbours=neighbours,
            )  # fmt: skip
            R, t_solved = self.refiner.refine(inp)
        try:
            ground = view.camera.backproject_to_plane(centre[None], self.view_z_eff_[best])[0]
            ground[2] = self.view_z_origin_[best]
            t_geo = camera_point(view.camera, ground)
        except ValueError:  # viewing ray parallel to the table: only the regressed one is left
            t_geo = t_reg
        if t_solved is not None:
            t_geo = t_solved
        lap("refine")
        if not (np.isfinite(R).all() and np.isfinite(t_geo).all()):
            return invalid("the stages gave a non-finite pose (corrupt model?)", len(f))
        tm["total"] = (time.perf_counter() - t0) * 1e3
        n_inl = len(best_inl)
        # Fraction of keypoints explained, discounted when the inlier count itself is small.
        conf = (len(kept) / len(f)) * min(1.0, n_inl / (3.0 * self.matcher.min_inliers))
        return PoseEstimate(
            rotation=R,
            translation=t_geo,
            confidence=float(conf),
            valid=True,
            timings_ms=tm,
            rotation_coarse=R_coarse,
            translation_regressed=t_reg,
            n_keypoints=len(f),
            n_inliers=n_inl,
        )

    # ---------------------------------------------------------------- save/load
    def to_arrays(self, prefix: str = "") -> dict[str, np.ndarray]:
        from pose.manifold.persistence import estimator_to_arrays

        return estimator_to_arrays(self, prefix)

    @classmethod
    def from_arrays(
        cls, arrays: dict[str, np.ndarray], prefix: str = "", format_version: int | None = None
    ) -> PoseManifoldEstimator:
        """The estimator saved by :meth:`to_arrays`; ``format_version`` is the file's (files of
        the previous version, with flat parameters, are translated to stage objects)."""
        from pose.manifold.persistence import estimator_from_arrays

        return estimator_from_arrays(cls, arrays, prefix, format_version)

    def save(self, path: str | os.PathLike) -> None:
        """Write the fitted estimator to one ``.npz`` file (atomic, pickle-free, versioned)."""
        from pose.serialization import save_arrays

        save_arrays(path, self.to_arrays(), {"kind": "estimator"})

    @classmethod
    def load(cls, path: str | os.PathLike) -> PoseManifoldEstimator:
        from pose.serialization import load_arrays

        header, arrays = load_arrays(path)
        if header.get("kind") != "estimator":
            raise ValueError(f"{path} holds a {header.get('kind')!r}, not a single estimator")
        return cls.from_arrays(arrays, format_version=header["format_version"])
