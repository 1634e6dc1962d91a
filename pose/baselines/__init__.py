"""Pose-estimation baselines with the manifold estimator's contract.

Every class here follows :class:`pose.manifold.estimator.PoseManifoldEstimator`'s contract:
``fit(views, poses)`` with ``camera_from_object`` poses ``(N, 4, 4)``, ``predict(view) ->
PoseEstimate`` (``valid=False``, never an exception, for a view without the object), and
pickle-free ``save``/``load``. They are registered by name in :mod:`pose.registry`:

==================  ==============================================================
``chance``          :class:`ChanceEstimator`: image-blind constant rotation
``pca-nn``          :class:`PCAEstimator` (``regressor="nn"``): appearance eigenspace, nearest view
``pca-rbf``         :class:`PCAEstimator` (``regressor="rbf"``): eigenspace + RBF network
``least-squares``   :class:`LeastSquaresEstimator`: linear map eigenspace -> rotation
``part-based``      :class:`PartBasedEstimator`: grid-of-parts manifold with visibility
``n3m``             :class:`N3MEstimator`: Natural 3D Markers, per-marker PnP
``sift-pnp``        :class:`SiftPnPEstimator`: SIFT to depth-lifted 3-D points, RANSAC PnP
``nearest-view``    :class:`NearestViewEstimator`: best SIFT view + homography in-plane angle
==================  ==============================================================

Each module's docstring says what it simplifies from its paper. The appearance baselines
(``chance``, ``pca-*``, ``least-squares``, ``part-based``) need masks; the keypoint ones
(``n3m``, ``sift-pnp``) need ``View.depth`` in the training views.
"""

from pose.baselines.chance import ChanceEstimator
from pose.baselines.least_squares import LeastSquaresEstimator
from pose.baselines.n3m import N3MEstimator
from pose.baselines.nearest_view import NearestViewEstimator
from pose.baselines.part_based import PartBasedEstimator
from pose.baselines.pca import PCAEstimator
from pose.baselines.pnp import SiftPnPEstimator

__all__ = [
    "ChanceEstimator",
    "LeastSquaresEstimator",
    "N3MEstimator",
    "NearestViewEstimator",
    "PCAEstimator",
    "PartBasedEstimator",
    "SiftPnPEstimator",
]
