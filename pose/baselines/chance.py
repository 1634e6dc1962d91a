"""The image-blind chance level: one constant rotation, whatever the view shows.

Every table of pose results needs the score of an answer that ignores the image: on a fixed
camera, objects resting upright on the table have only a few distinct rotations up to
symmetry, so a constant answer is right more often than "chance" suggests (an upright can is
always right under its axial symmetry). :class:`ChanceEstimator` answers the *medoid* of the
training rotations — the one with the smallest summed geodesic distance to all others, i.e. the
most common resting face at a typical heading. Both are taken in the world frame (through each
view's camera extrinsics) and the answer is turned into the test view's camera frame: an object
resting on the table is upright whichever camera looks at it, so the constant answer stays the
image-blind reference when the test camera is not a training camera (``cross-camera``); in one
camera's frame it would be a rotation that no test view can have. It is placed at the mask
centroid with the
shared silhouette position (:class:`pose.baselines._common.BaselineEstimator`), so that its
position error is the same reference as every other baseline's.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from sklearn.utils.validation import check_is_fitted

from pose.baselines._common import (
    BaselineEstimator,
    Timer,
    check_training_set,
    check_view,
    invalid,
    object_region,
    require_masks,
)
from pose.geometry import centre_and_size
from pose.rotations import geodesic_deg
from pose.view import PoseEstimate, View


class ChanceEstimator(BaselineEstimator):
    """Constant rotation (the training medoid), position from the mask centroid.

    ``predict`` is ``valid=False`` only when the view has no object mask: the position needs
    one, the rotation needs nothing.
    """

    _FITTED = ("medoid_", "medoid_world_", *BaselineEstimator.TRANSLATION)

    def fit(self, views: Sequence[View], poses) -> ChanceEstimator:
        views, P = check_training_set(views, poses)
        require_masks(views, "ChanceEstimator")
        R = np.stack(
            [v.camera.world_from_camera[:3, :3] @ p[:3, :3] for v, p in zip(views, P, strict=True)]
        )
        cost = np.array([geodesic_deg(R, r[None]).sum() for r in R])
        # Symmetric training grids make many rotations equally central, up to float noise that
        # differs between machines and library versions (arccos near the identity magnifies it
        # to ~1e-5 degrees): every rotation within 1e-3 degrees of the least summed distance
        # is a tie, and the first of them is taken. Rounding instead splits ties at a rounding
        # boundary differently from one machine to the next.
        tied = np.flatnonzero(cost <= cost.min() + 1e-3)
        self.medoid_ = np.array(int(tied[0]))
        self.medoid_world_ = R[int(self.medoid_)].copy()
        self._fit_translation(views, P)
        return self

    def _predict_one(self, view: View) -> PoseEstimate:
        check_is_fitted(self, "medoid_")
        check_view(view)
        timer = Timer()
        region = object_region(view)
        if region is None:
            return invalid("no object mask", timer)
        centre, size = centre_and_size(region, np.zeros((1, 2)))
        t = self._translation(view.camera, centre, size, int(self.medoid_))
        R = view.camera.camera_from_world[:3, :3] @ self.medoid_world_
        timer.lap("constant")
        return PoseEstimate(
            rotation=R,
            translation=t,
            confidence=0.0,
            valid=True,
            timings_ms=timer.done(),
            rotation_coarse=R.copy(),
            translation_regressed=t,
        )
