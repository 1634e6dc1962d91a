"""Old import path of :mod:`pose.manifold.bunches` (stage c), kept for existing code."""

from pose.manifold.bunches import Bunches, KMeansBunches, kmeans_locations, make_bunches

__all__ = ["Bunches", "KMeansBunches", "kmeans_locations", "make_bunches"]
