"""Baseline classifiers on the same shape descriptors: k-NN and an RBF SVM.

Both are scikit-learn pipelines with a ``StandardScaler`` in front, because the descriptor
blocks live on very different scales (Fourier ratios, ART ratios, rooted moment invariants),
followed by :class:`FeatureWeights`, so that block weighting can be tuned for the baselines
exactly as FLR's ``feature_weights`` is.
"""

from __future__ import annotations

import numpy as np
from sklearn.base import BaseEstimator, TransformerMixin
from sklearn.neighbors import KNeighborsClassifier
from sklearn.pipeline import Pipeline, make_pipeline
from sklearn.preprocessing import StandardScaler
from sklearn.svm import SVC
from sklearn.utils.validation import check_is_fitted, validate_data

from pose.shape.flr import FLRClassifier


class FeatureWeights(TransformerMixin, BaseEstimator):
    """Multiply each feature by a fixed non-negative weight (``None``: identity)."""

    def __init__(self, weights=None) -> None:
        self.weights = weights

    def fit(self, X, y=None) -> FeatureWeights:
        X = validate_data(self, X)
        if self.weights is None:
            self.weights_ = np.ones(X.shape[1])
        else:
            w = np.asarray(self.weights, dtype=np.float64)
            if w.shape != (X.shape[1],) or not np.all(np.isfinite(w)) or np.any(w < 0):
                raise ValueError(
                    f"weights must be {X.shape[1]} finite non-negative numbers, got {w.shape}"
                )
            self.weights_ = w
        return self

    def transform(self, X) -> np.ndarray:
        check_is_fitted(self, "weights_")
        return validate_data(self, X, reset=False) * self.weights_


def make_knn(n_neighbors: int = 3) -> Pipeline:
    """StandardScaler + feature weights + distance-weighted k-nearest-neighbours."""
    return make_pipeline(
        StandardScaler(),
        FeatureWeights(),
        KNeighborsClassifier(n_neighbors=n_neighbors, weights="distance"),
    )


def make_svm(C: float = 10.0, gamma: str | float = "scale", seed: int = 0) -> Pipeline:
    """StandardScaler + feature weights + RBF support-vector machine (one-vs-one)."""
    return make_pipeline(
        StandardScaler(), FeatureWeights(), SVC(C=C, gamma=gamma, random_state=seed)
    )


def make_classifiers(seed: int = 0) -> dict:
    """The three classifiers compared in the benchmark, keyed by short name."""
    return {"flr": FLRClassifier(random_state=seed), "knn": make_knn(), "svm": make_svm(seed=seed)}
