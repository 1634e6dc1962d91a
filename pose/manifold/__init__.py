"""The pose-manifold estimator and its stages (bunches, anchor distances, reference direction,
featurizer, regressors, refinement); keypoints and matching are in :mod:`pose.features`.

``from pose.manifold import anchor_index, manifold_coordinates`` keeps working for code written
when this package was the single module ``pose/manifold.py``.
"""

from pose.manifold.bunches import Bunches, KMeansBunches, make_bunches
from pose.manifold.coordinates import anchor_index, manifold_coordinates, pairwise_coordinates
from pose.manifold.estimator import PoseManifoldEstimator, default_regressor
from pose.manifold.featurizer import ManifoldFeaturizer
from pose.manifold.reference import KeypointHeading, SilhouetteDirection
from pose.manifold.refinement import HomographyRefiner, PnPRefiner
from pose.manifold.regressors import NearestNeighbourRegressor, RBFNetwork, ScipyRBF
from pose.manifold.variants import VARIANTS, make_variant

__all__ = [
    "VARIANTS",
    "Bunches",
    "HomographyRefiner",
    "PnPRefiner",
    "KMeansBunches",
    "KeypointHeading",
    "ManifoldFeaturizer",
    "NearestNeighbourRegressor",
    "PoseManifoldEstimator",
    "RBFNetwork",
    "ScipyRBF",
    "SilhouetteDirection",
    "anchor_index",
    "default_regressor",
    "make_bunches",
    "make_variant",
    "manifold_coordinates",
    "pairwise_coordinates",
]
