"""Appearance PCA (Murase and Nayar's parametric eigenspace; the seed's reference [34]).

The object is cropped by its mask and normalised for scale and brightness
(:func:`pose.baselines._common.appearance_patch`); PCA of the training patches gives a
low-dimensional eigenspace in which every training view is a point labelled with its pose.
A new view is projected into the eigenspace and its pose read off either from the nearest
training point (``regressor="nn"``, the original method, registered as ``pca-nn``) or from an
RBF network over the eigenspace coordinates (``regressor="rbf"``, the seed's comparison,
registered as ``pca-rbf``).

Simplifications against the papers: one eigenspace per object (no universal eigenspace for
recognition); the manifold is the set of training points, not a spline through them; patches
are cut by the visible mask, so an occluder shifts and rescales the crop (the original work
assumed unoccluded, segmented objects). The RBF regresses the camera-frame rotation in the
6-D representation (:mod:`pose.rotations`) and projects it onto SO(3); a symmetric object's
views that look alike but carry different labels are averaged, which is the point of the
comparison.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from sklearn.decomposition import PCA
from sklearn.utils.validation import check_is_fitted

from pose.baselines._common import (
    BaselineEstimator,
    appearance_input,
    appearance_patch,
    check_training_set,
    nearest_rotation,
    object_region,
    require_masks,
)
from pose.geometry import centre_and_size
from pose.manifold.regressors import RBFNetwork
from pose.rotations import from_6d, to_6d
from pose.view import PoseEstimate, View

REGRESSORS = ("nn", "rbf")


class PCAEstimator(BaselineEstimator):
    """Eigenspace of mask-cropped appearance; pose by nearest neighbour or RBF regression.

    ``n_components`` eigenvectors of ``patch_size x patch_size`` patches; ``regressor`` is
    ``"nn"`` or ``"rbf"`` (``n_centers``, ``width_scale``, ``ridge``: the RBF network's;
    narrow normalised units, as the manifold estimator uses, because nearby views of different
    resting faces must not be blended).
    """

    _FITTED = ("mean_", "components_", "coords_", *BaselineEstimator.TRANSLATION)

    def __init__(
        self,
        n_components: int = 20,
        patch_size: int = 32,
        regressor: str = "nn",
        n_centers: int = 1000,
        width_scale: float = 0.3,
        ridge: float = 1e-4,
        random_state: int = 0,
    ):
        self.n_components = n_components
        self.patch_size = patch_size
        self.regressor = regressor
        self.n_centers = n_centers
        self.width_scale = width_scale
        self.ridge = ridge
        self.random_state = random_state

    @property
    def _SUBMODELS(self) -> tuple[str, ...]:  # noqa: N802 - the base class's attribute name
        return ("regressor_",) if self.regressor == "rbf" else ()

    def _new_submodel(self, name: str) -> RBFNetwork:
        return RBFNetwork(
            n_centers=self.n_centers,
            width_scale=self.width_scale,
            alpha=self.ridge,
            normalized=True,
            random_state=self.random_state,
        )

    def _validate_params(self) -> None:
        if self.regressor not in REGRESSORS:
            raise ValueError(f"regressor must be one of {REGRESSORS}, got {self.regressor!r}")
        if self.n_components < 1 or self.patch_size < 8:
            raise ValueError(
                f"need n_components >= 1 and patch_size >= 8, got {self.n_components}, "
                f"{self.patch_size}"
            )

    def _project(self, patch: np.ndarray) -> np.ndarray:
        return (np.atleast_2d(patch) - self.mean_) @ self.components_.T

    def fit(self, views: Sequence[View], poses) -> PCAEstimator:
        self._validate_params()
        views, P = check_training_set(views, poses)
        require_masks(views, type(self).__name__)
        X = np.array([appearance_patch(v.image, object_region(v), self.patch_size) for v in views])
        k = min(self.n_components, len(views), X.shape[1])
        pca = PCA(n_components=k, random_state=self.random_state).fit(X)
        self.mean_ = pca.mean_.astype(np.float32)
        self.components_ = pca.components_.astype(np.float32)
        self.coords_ = self._project(X)
        if self.regressor == "rbf":
            self.regressor_ = self._new_submodel("regressor_").fit(
                self.coords_, to_6d(P[:, :3, :3])
            )
        self._fit_translation(views, P)
        return self

    def _predict_one(self, view: View) -> PoseEstimate:
        check_is_fitted(self, "coords_")
        timer, region, failed = appearance_input(view)
        if failed is not None:
            return failed
        z = self._project(appearance_patch(view.image, region, self.patch_size))
        timer.lap("project")
        d = np.linalg.norm(self.coords_ - z, axis=1)
        nn = int(np.argmin(d))
        if self.regressor == "rbf":
            R = from_6d(self.regressor_.predict(z)[0])
            ref = nearest_rotation(R, self.tr_rotation_)
        else:
            R, ref = self.tr_rotation_[nn].copy(), nn
        timer.lap("regress")
        centre, size = centre_and_size(region, np.zeros((1, 2)))
        t = self._translation(view.camera, centre, size, ref)
        # Distance in the eigenspace against the spread of the training set: 1 on a training
        # view, towards 0 for a view unlike any of them.
        conf = float(np.exp(-d[nn] / max(float(np.median(d)), 1e-9)))
        return PoseEstimate(
            rotation=R,
            translation=t,
            confidence=conf,
            valid=True,
            timings_ms=timer.done(),
            rotation_coarse=R.copy(),
            translation_regressed=t,
        )
