"""Named compositions of the pose-manifold estimator: the stage-ablation variants.

Each variant differs from ``manifold`` (the default composition) by one swapped stage, so a
table over these names isolates what each stage contributes. :mod:`pose.registry` registers them
all; extra parameters, nested ones included (``bunches__n_bunches=6``), go through
``set_params`` on top of the variant's stages.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from pose.manifold.estimator import PoseManifoldEstimator
from pose.manifold.featurizer import ManifoldFeaturizer
from pose.manifold.reference import SilhouetteDirection
from pose.manifold.refinement import PnPRefiner
from pose.manifold.regressors import NearestNeighbourRegressor, ScipyRBF

# name -> (what it changes, factory of the swapped stages: fresh objects on every call)
VARIANTS: dict[str, tuple[str, Callable[[], dict[str, Any]]]] = {
    "manifold": ("default composition", dict),
    "manifold-coarse": ("no refinement (refiner=None)", lambda: {"refiner": None}),
    "manifold-pnp": (
        "RANSAC PnP on the matched keypoints' 3-D points instead of the homography refiner",
        lambda: {"refiner": PnPRefiner()},
    ),
    "manifold-no-bunches": (
        "no bunch block (silhouette + visual words only)",
        lambda: {"featurizer": ManifoldFeaturizer(blocks=("shape", "words"))},
    ),
    "manifold-no-shape": (
        "no silhouette block",
        lambda: {"featurizer": ManifoldFeaturizer(blocks=("bunches", "words"))},
    ),
    "manifold-no-words": (
        "no visual-word block",
        lambda: {"featurizer": ManifoldFeaturizer(blocks=("bunches", "shape"))},
    ),
    "manifold-no-anchor": (
        "sorted pairwise bunch distances instead of distances to the anchor bunch",
        lambda: {"featurizer": ManifoldFeaturizer(anchor=None)},
    ),
    "manifold-knn": (
        "nearest-neighbour lookup instead of the RBF network",
        lambda: {"regressor": NearestNeighbourRegressor()},
    ),
    "manifold-scipy": (
        "scipy RBFInterpolator (linear kernel) instead of the RBF network",
        lambda: {"regressor": ScipyRBF(smoothing=1e-4, standardize=False)},
    ),
    "manifold-silhouette-reference": (
        "silhouette axis instead of the keypoint-voted heading",
        lambda: {"reference": SilhouetteDirection()},
    ),
}


def make_variant(name: str, **params: Any) -> PoseManifoldEstimator:
    """A new estimator of the named composition, then ``set_params(**params)``."""
    if name not in VARIANTS:
        raise ValueError(f"unknown manifold variant {name!r}; valid: {', '.join(VARIANTS)}")
    return PoseManifoldEstimator(**VARIANTS[name][1]()).set_params(**params)
