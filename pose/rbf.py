"""Old import path of the regressors in :mod:`pose.manifold.regressors`, kept for existing code."""

from pose.manifold.regressors import NearestNeighbourRegressor, RBFNetwork, ScipyRBF

__all__ = ["NearestNeighbourRegressor", "RBFNetwork", "ScipyRBF"]
