"""Linear least squares from appearance to rotation (the seed's "least-squares solution").

The seed compared its RBF regressor against the simplest possible learned map: a linear
function from the appearance coordinates to the pose, fitted by least squares. Here the
coordinates are the appearance-PCA eigenspace of :mod:`pose.baselines.pca`, the target the
camera-frame rotation in the 6-D representation, and the fit ridge-regularised (``alpha``)
so that it is well posed with more components than views; the answer is projected onto
SO(3). Simplification: the seed's input was its own manifold coordinates; using the same
eigenspace as ``pca-nn``/``pca-rbf`` keeps the comparison about the regressor alone. A
heading is a circular quantity, so no linear map can follow a full turn: the baseline shows
how much of the problem is non-linear.
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
from pose.rotations import from_6d, to_6d
from pose.view import PoseEstimate, View


class LeastSquaresEstimator(BaselineEstimator):
    """Ridge least squares from ``n_components`` appearance-PCA coordinates to the 6-D rotation."""

    _FITTED = ("mean_", "components_", "weights_", *BaselineEstimator.TRANSLATION)

    def __init__(
        self, n_components: int = 20, patch_size: int = 32, alpha: float = 1e-3, random_state=0
    ):
        self.n_components = n_components
        self.patch_size = patch_size
        self.alpha = alpha
        self.random_state = random_state

    def _design(self, patches: np.ndarray) -> np.ndarray:
        Z = (np.atleast_2d(patches) - self.mean_) @ self.components_.T
        return np.c_[Z, np.ones(len(Z))]

    def fit(self, views: Sequence[View], poses) -> LeastSquaresEstimator:
        if self.n_components < 1 or self.patch_size < 8 or self.alpha < 0:
            raise ValueError(
                "need n_components >= 1, patch_size >= 8 and alpha >= 0, got "
                f"{self.n_components}, {self.patch_size}, {self.alpha}"
            )
        views, P = check_training_set(views, poses)
        require_masks(views, type(self).__name__)
        X = np.array([appearance_patch(v.image, object_region(v), self.patch_size) for v in views])
        k = min(self.n_components, len(views), X.shape[1])
        pca = PCA(n_components=k, random_state=self.random_state).fit(X)
        self.mean_ = pca.mean_.astype(np.float32)
        self.components_ = pca.components_.astype(np.float32)
        A = self._design(X)
        reg = self.alpha * np.eye(A.shape[1])
        reg[-1, -1] = 0.0  # do not shrink the bias
        self.weights_ = np.linalg.solve(A.T @ A + reg, A.T @ to_6d(P[:, :3, :3]))
        self._fit_translation(views, P)
        return self

    def _predict_one(self, view: View) -> PoseEstimate:
        check_is_fitted(self, "weights_")
        timer, region, failed = appearance_input(view)
        if failed is not None:
            return failed
        y = self._design(appearance_patch(view.image, region, self.patch_size)) @ self.weights_
        R = from_6d(y[0])
        timer.lap("regress")
        centre, size = centre_and_size(region, np.zeros((1, 2)))
        t = self._translation(view.camera, centre, size, nearest_rotation(R, self.tr_rotation_))
        return PoseEstimate(
            rotation=R,
            translation=t,
            confidence=0.0,
            valid=True,
            timings_ms=timer.done(),
            rotation_coarse=R.copy(),
            translation_regressed=t,
        )
