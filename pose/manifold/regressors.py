"""Stage e: regressors from manifold coordinates to pose.

``RBFNetwork`` is the paper's radial-basis-function network: Gaussian units centred by k-means,
widths from the spacing of the centres, and a ridge-regularised linear output layer solved in
closed form. ``ScipyRBF`` wraps :class:`scipy.interpolate.RBFInterpolator` as the alternative,
and ``NearestNeighbourRegressor`` is the lookup baseline the RBF is measured against. All
standardise their inputs (optionally) and can be saved as plain arrays (no pickle): the pose
estimator saves any regressor with ``to_arrays`` / ``load_arrays``.
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import RBFInterpolator
from sklearn.base import BaseEstimator, RegressorMixin
from sklearn.cluster import KMeans
from sklearn.utils.validation import check_is_fitted


def _check_xy(X, y=None):
    X = np.asarray(X, float)
    if X.ndim != 2 or len(X) == 0:
        raise ValueError(f"X must be a non-empty 2-D array, got shape {X.shape}")
    if not np.isfinite(X).all():
        raise ValueError("X contains NaN or infinite values")
    if y is None:
        return X
    y = np.asarray(y, float)
    if len(y) != len(X):
        raise ValueError(f"X has {len(X)} rows but y has {len(y)}")
    return X, y.reshape(len(y), -1)


def _squared_distances(A: np.ndarray, B: np.ndarray, block: int = 64) -> np.ndarray:
    """``||A_i - B_j||^2`` for every pair, ``(len(A), len(B))``.

    The same arithmetic as one broadcast ``((A[:, None] - B[None]) ** 2).sum(axis=2)``, so the
    same bits, but ``block`` rows of ``A`` at a time: with a thousand centres the broadcast
    makes a temporary of hundreds of MB, whose allocation costs more than the arithmetic.
    """
    out = np.empty((len(A), len(B)))
    for i in range(0, len(A), block):
        out[i : i + block] = ((A[i : i + block, None, :] - B[None]) ** 2).sum(axis=2)
    return out


def _standardizer(X: np.ndarray, on: bool) -> tuple[np.ndarray, np.ndarray]:
    if not on:
        return np.zeros(X.shape[1]), np.ones(X.shape[1])
    sd = X.std(axis=0)
    return X.mean(axis=0), np.where(sd > 1e-12, sd, 1.0)


class RBFNetwork(RegressorMixin, BaseEstimator):
    """Gaussian RBF network: ``y = W^T [phi_1(x) .. phi_m(x), 1]``.

    ``phi_j(x) = exp(-||x - c_j||^2 / (2 sigma_j^2))`` with ``sigma_j = width_scale`` times the
    mean distance from ``c_j`` to its ``n_neighbors`` nearest other centres. ``normalized=True``
    divides the units by their sum (Moody and Darken's normalised RBF): far from every centre the
    output is then the nearest centres' answer instead of decaying to the bias, which suits
    targets that are nearly piecewise constant (one rotation per resting face).
    """

    def __init__(
        self,
        n_centers: int = 64,
        width_scale: float = 1.0,
        alpha: float = 1e-6,
        n_neighbors: int = 2,
        standardize: bool = True,
        normalized: bool = False,
        random_state: int = 0,
    ):
        self.n_centers = n_centers
        self.standardize = standardize
        self.width_scale = width_scale
        self.alpha = alpha
        self.n_neighbors = n_neighbors
        self.normalized = normalized
        self.random_state = random_state

    def fit(self, X, y):
        X, y = _check_xy(X, y)
        if self.n_centers < 1 or self.alpha < 0 or self.width_scale <= 0:
            raise ValueError("need n_centers >= 1, alpha >= 0 and width_scale > 0")
        self.x_mean_, self.x_scale_ = _standardizer(X, self.standardize)
        Z = (X - self.x_mean_) / self.x_scale_
        distinct = np.unique(Z, axis=0)
        m = min(self.n_centers, len(distinct))
        if m == len(distinct):  # one unit per sample: k-means would only reproduce them
            self.centers_ = distinct
        else:
            km = KMeans(n_clusters=m, n_init=3, random_state=self.random_state).fit(Z)
            self.centers_ = km.cluster_centers_
        if m > 1:
            dc = np.sqrt(_squared_distances(self.centers_, self.centers_))
            np.fill_diagonal(dc, np.inf)
            nn = np.sort(dc, axis=1)[:, : min(self.n_neighbors, m - 1)]
            self.widths_ = self.width_scale * nn.mean(axis=1)
        else:
            self.widths_ = np.array([self.width_scale * max(Z.std(), 1.0)])
        P = self._design(Z)
        reg = self.alpha * np.eye(P.shape[1])
        reg[-1, -1] = 0.0  # do not shrink the bias
        self.weights_ = np.linalg.solve(P.T @ P + reg, P.T @ y)
        self.n_outputs_ = y.shape[1]
        return self

    def _design(self, Z: np.ndarray) -> np.ndarray:
        d2 = _squared_distances(Z, self.centers_)
        e = -d2 / (2 * self.widths_**2)
        if self.normalized:  # softmax: stable however far the point is from every centre
            e = np.exp(e - e.max(axis=1, keepdims=True))
            return np.c_[e / e.sum(axis=1, keepdims=True), np.ones(len(Z))]
        return np.c_[np.exp(e), np.ones(len(Z))]

    def predict(self, X) -> np.ndarray:
        check_is_fitted(self, "weights_")
        X = _check_xy(X)
        return self._design((X - self.x_mean_) / self.x_scale_) @ self.weights_

    _ARRAYS = ("x_mean_", "x_scale_", "centers_", "widths_", "weights_")

    def to_arrays(self) -> dict[str, np.ndarray]:
        return {k: getattr(self, k) for k in self._ARRAYS}

    def load_arrays(self, arrays: dict[str, np.ndarray]) -> RBFNetwork:
        for k in self._ARRAYS:
            setattr(self, k, np.asarray(arrays[k], float))
        self.n_outputs_ = self.weights_.shape[1]
        return self


class ScipyRBF(RegressorMixin, BaseEstimator):
    """:class:`scipy.interpolate.RBFInterpolator` on standardised inputs (smoothing > 0).

    The default polyharmonic ``linear`` kernel with a constant term (``degree=0``) needs no
    shape parameter and, unlike the thin-plate spline's degree-1 polynomial, no more samples
    than input dimensions (the manifold input has about 80).
    """

    def __init__(
        self,
        kernel: str = "linear",
        smoothing: float = 1e-3,
        degree: int = 0,
        neighbors: int | None = None,
        standardize: bool = True,
    ):
        self.standardize = standardize
        self.kernel = kernel
        self.degree = degree
        self.smoothing = smoothing
        self.neighbors = neighbors

    def fit(self, X, y):
        X, y = _check_xy(X, y)
        self.x_mean_, self.x_scale_ = _standardizer(X, self.standardize)
        self.X_, self.y_ = X, y
        self._build()
        return self

    def _build(self) -> None:
        Z = (self.X_ - self.x_mean_) / self.x_scale_
        self._interp = RBFInterpolator(
            Z,
            self.y_,
            kernel=self.kernel,
            smoothing=self.smoothing,
            degree=self.degree,
            neighbors=self.neighbors,
        )

    def predict(self, X) -> np.ndarray:
        check_is_fitted(self, "X_")
        X = _check_xy(X)
        return self._interp((X - self.x_mean_) / self.x_scale_)

    _ARRAYS = ("x_mean_", "x_scale_", "X_", "y_")

    def to_arrays(self) -> dict[str, np.ndarray]:
        return {k: getattr(self, k) for k in self._ARRAYS}

    def load_arrays(self, arrays: dict[str, np.ndarray]) -> ScipyRBF:
        for k in self._ARRAYS:
            setattr(self, k, np.asarray(arrays[k], float))
        self._build()
        return self


class NearestNeighbourRegressor(RegressorMixin, BaseEstimator):
    """Mean target of the ``n_neighbors`` nearest training inputs (Euclidean).

    The ablation baseline for the RBF network: a plain lookup among the training views'
    manifold vectors, with no interpolation between them.
    """

    def __init__(self, n_neighbors: int = 1, standardize: bool = False):
        self.n_neighbors = n_neighbors
        self.standardize = standardize

    def fit(self, X, y):
        X, y = _check_xy(X, y)
        if self.n_neighbors < 1:
            raise ValueError(f"n_neighbors must be >= 1, got {self.n_neighbors}")
        self.x_mean_, self.x_scale_ = _standardizer(X, self.standardize)
        self.X_, self.y_ = (X - self.x_mean_) / self.x_scale_, y
        return self

    def predict(self, X) -> np.ndarray:
        check_is_fitted(self, "X_")
        Z = (_check_xy(X) - self.x_mean_) / self.x_scale_
        d2 = (Z**2).sum(1)[:, None] - 2 * Z @ self.X_.T + (self.X_**2).sum(1)[None]
        k = min(self.n_neighbors, len(self.X_))
        nearest = np.argsort(d2, axis=1, kind="stable")[:, :k]
        return self.y_[nearest].mean(axis=1)

    _ARRAYS = ("x_mean_", "x_scale_", "X_", "y_")

    def to_arrays(self) -> dict[str, np.ndarray]:
        return {k: getattr(self, k) for k in self._ARRAYS}

    def load_arrays(self, arrays: dict[str, np.ndarray]) -> NearestNeighbourRegressor:
        for k in self._ARRAYS:
            setattr(self, k, np.asarray(arrays[k], float))
        return self
