"""Stage d': the in-plane reference direction, as swappable stage objects.

The rotation is regressed relative to this direction and the anchor bunch is chosen along it,
so it must turn with the object. :class:`KeypointHeading` (the default) is voted by the inlier
keypoints against the canonical orientations learnt in training
(:func:`pose.orientation.keypoint_heading`); :class:`SilhouetteDirection` is the older
silhouette long axis / saturation centroid (:func:`pose.orientation.reference_angle`), kept as
an ablation.

Both answer two questions: the angle of a *training* view, whose rotation relative to the
camera is known, and the angle of a *query* view, from its image, region and its inliers'
orientations against the canonical ones of their nearest training descriptors.
"""

from __future__ import annotations

import numpy as np
from sklearn.base import BaseEstimator

from pose.orientation import keypoint_heading, reference_angle
from pose.rotations import inplane_heading


class KeypointHeading(BaseEstimator):
    """Texture-anchored heading. In training it is the in-plane heading of the known rotation
    (:func:`pose.rotations.inplane_heading`); at query time the keypoints' SIFT orientations
    minus their canonical ones vote, with votes within ``window_deg`` of the peak averaged."""

    def __init__(self, window_deg: float = 20.0):
        self.window_deg = window_deg

    def validate(self) -> None:
        if not 0 < self.window_deg <= 180:
            raise ValueError(f"window_deg must be in (0, 180], got {self.window_deg}")

    def training_angle(
        self, image: np.ndarray, region: np.ndarray, centre: np.ndarray, R_rel: np.ndarray
    ) -> float:
        return inplane_heading(R_rel)

    def query_angle(
        self,
        image: np.ndarray,
        region: np.ndarray,
        centre: np.ndarray,
        angles: np.ndarray,
        canonical: np.ndarray,
    ) -> float:
        return keypoint_heading(angles, canonical, self.window_deg)[0]


class SilhouetteDirection(BaseEstimator):
    """The silhouette's long axis (elongated shapes) or saturation centroid (round ones); it
    ignores the keypoints and, for training views, the known rotation."""

    def validate(self) -> None:
        return None

    def training_angle(
        self, image: np.ndarray, region: np.ndarray, centre: np.ndarray, R_rel: np.ndarray
    ) -> float:
        return reference_angle(image, region, centre)

    def query_angle(
        self,
        image: np.ndarray,
        region: np.ndarray,
        centre: np.ndarray,
        angles: np.ndarray,
        canonical: np.ndarray,
    ) -> float:
        return reference_angle(image, region, centre)
