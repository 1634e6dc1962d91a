"""Optional last stage: refine the coarse rotation with the best training view's homography.

The homography to the best-matching training view, linearised at the object centre, gives the
in-plane angle between the two views; that training view's known rotation turned by this angle
about the optical axis replaces the manifold's answer. It helps most at high occlusion on
box-like objects, where few bunches are left to describe the aspect. ``refiner=None`` in the
estimator keeps the pure manifold answer (``PoseEstimate.rotation_coarse`` always holds it).
"""

from __future__ import annotations

import numpy as np
from sklearn.base import BaseEstimator

from pose.rotations import rot_z


class HomographyRefiner(BaseEstimator):
    """Rotation of the best-matching training view, turned by the homography's in-plane angle.

    ``R_ray`` maps the (allocentric) training rotation back to the camera frame (the identity
    for egocentric models)."""

    def validate(self) -> None:
        return None

    def refine(
        self, R_coarse: np.ndarray, R_ray: np.ndarray, angle: float, R_view: np.ndarray
    ) -> np.ndarray:
        return R_ray @ rot_z(angle) @ R_view
