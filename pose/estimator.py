"""Old import path of :class:`~pose.manifold.estimator.PoseManifoldEstimator`.

The estimator and its stages live in :mod:`pose.manifold` (bunches, reference direction,
featurizer, regressors, refinement) and :mod:`pose.features` (keypoints, matching).
"""

from pose.manifold.augment import occlude_features
from pose.manifold.estimator import PoseManifoldEstimator
from pose.manifold.featurizer import N_SHAPE, SHAPE_SIDE, shape_features

__all__ = ["N_SHAPE", "SHAPE_SIDE", "PoseManifoldEstimator", "occlude_features", "shape_features"]
