"""Pose estimators by name: ``make_estimator("manifold", bunches__n_bunches=6)``.

Every registered estimator follows the same contract — ``fit(views, poses)`` with
``camera_from_object`` poses ``(N, 4, 4)``, ``predict(view) -> PoseEstimate`` — so an ablation
is a swap of names (the CLI, the sweep runner and the pose sources all resolve them here).
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import Any

from pose import baselines
from pose.estimator import PoseManifoldEstimator

_ESTIMATORS: dict[str, Callable[..., Any]] = {"manifold": PoseManifoldEstimator}
_ESTIMATORS["chance"] = baselines.ChanceEstimator
_ESTIMATORS["pca-nn"] = partial(baselines.PCAEstimator, regressor="nn")
_ESTIMATORS["pca-rbf"] = partial(baselines.PCAEstimator, regressor="rbf")
_ESTIMATORS["least-squares"] = baselines.LeastSquaresEstimator
_ESTIMATORS["part-based"] = baselines.PartBasedEstimator
_ESTIMATORS["n3m"] = baselines.N3MEstimator
_ESTIMATORS["sift-pnp"] = baselines.SiftPnPEstimator
_ESTIMATORS["nearest-view"] = baselines.NearestViewEstimator


def estimator_names() -> tuple[str, ...]:
    return tuple(sorted(_ESTIMATORS))


def register_estimator(name: str, factory: Callable[..., Any], *, overwrite: bool = False) -> None:
    """Make ``make_estimator(name, **params)`` call ``factory(**params)``."""
    if not name or not isinstance(name, str):
        raise ValueError(f"an estimator needs a non-empty name, got {name!r}")
    if name in _ESTIMATORS and not overwrite:
        raise ValueError(f"estimator {name!r} is already registered (pass overwrite=True)")
    if not callable(factory):
        raise TypeError(f"factory for estimator {name!r} must be callable, got {factory!r}")
    _ESTIMATORS[name] = factory


def make_estimator(name: str, **params: Any) -> Any:
    """A new, unfitted estimator of the registered kind ``name``."""
    if name not in _ESTIMATORS:
        raise ValueError(f"unknown estimator {name!r}; registered: {', '.join(estimator_names())}")
    return _ESTIMATORS[name](**params)


# The pose-manifold estimator and its stage-ablation variants (pose.manifold.variants): each a
# swap of one stage; extra parameters, nested ones too (bunches__n_bunches=6), via set_params.
def _register_manifold_variants() -> None:
    from functools import partial

    from pose.manifold.variants import VARIANTS, make_variant

    for name in VARIANTS:
        register_estimator(name, partial(make_variant, name), overwrite=name == "manifold")


_register_manifold_variants()
