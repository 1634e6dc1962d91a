"""Privileged pose sources: the ground truth, and the ground truth corrupted on purpose.

``NoisyOraclePoseSource`` is dm_control's *corruptor* idea applied to the pose: controlled,
seeded noise and dropout on top of the truth, so that a policy's robustness can be plotted
against one knob at a time instead of against a whole estimator's error profile.
``OccludedOraclePoseSource`` adds the estimator's one systematic loss, the object hidden by
the hand, for training policies that act from a held estimate.
"""

from __future__ import annotations

from collections.abc import Sequence
from numbers import Real

import numpy as np

from scorbot_gym.perception.base import PerceptionFrame, WorldPose
from scorbot_gym.sim.simulation import quat_from_yaw, quat_mul, quat_to_mat


class OraclePoseSource:
    """The true object pose (the upper bound for any estimator)."""

    required_keys: tuple[str, ...] = ()
    privileged = True

    def reset(self, frame: PerceptionFrame, rng: np.random.Generator) -> None:
        pass

    def estimate(self, frame: PerceptionFrame) -> WorldPose:
        t = frame.truth
        return WorldPose(
            np.asarray(t["position"], float).copy(),
            np.asarray(t["quaternion"], float).copy(),
            True,
            1.0,
            object_name=frame.object_name,
        )

    def neighbours(self, frame: PerceptionFrame) -> np.ndarray:
        """The other objects' footprints from their true poses (``frame.truth["others"]`` on a
        cluttered table): points ``(N, 3)`` (:func:`~scorbot_gym.perception.neighbours.
        footprint_points`); none on a table with one object."""
        from scorbot_gym.objects import get_object
        from scorbot_gym.perception.neighbours import footprint_points
        from scorbot_gym.sim.scene import TABLE_HEIGHT

        points = [np.zeros((0, 3))]
        for name, truth in (frame.truth or {}).get("others", {}).items():
            R = quat_to_mat(np.asarray(truth["quaternion"], float))
            verts = get_object(name).mesh_vertices() @ R.T + np.asarray(truth["position"], float)
            points.append(footprint_points(verts, TABLE_HEIGHT))
        return np.vstack(points)


class NoisyOraclePoseSource(OraclePoseSource):
    """The true pose with Gaussian noise: ``pos_sigma_m`` on x and y (the table plane; table-top
    estimators know the height from the table), ``yaw_sigma_deg`` about the vertical, and each
    estimate lost with probability ``dropout`` (then ``valid=False``).

    Noise is drawn per estimate from the generator the wrapper seeds at every ``reset(seed)``.
    """

    def __init__(
        self, pos_sigma_m: float = 0.01, yaw_sigma_deg: float = 5.0, dropout: float = 0.0
    ) -> None:
        for name, v in (("pos_sigma_m", pos_sigma_m), ("yaw_sigma_deg", yaw_sigma_deg)):
            if not (_is_real(v) and np.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be a finite number >= 0, got {v!r}")
        if not (_is_real(dropout) and 0.0 <= dropout <= 1.0):
            raise ValueError(f"dropout must be a probability in [0, 1], got {dropout!r}")
        self.pos_sigma_m, self.yaw_sigma_deg, self.dropout = pos_sigma_m, yaw_sigma_deg, dropout
        self._rng = np.random.default_rng(0)

    def reset(self, frame: PerceptionFrame, rng: np.random.Generator) -> None:
        self._rng = rng

    def estimate(self, frame: PerceptionFrame) -> WorldPose:
        rng = self._rng
        lost = rng.random() < self.dropout
        dxy = rng.normal(0.0, self.pos_sigma_m, 2)
        dyaw = np.radians(rng.normal(0.0, self.yaw_sigma_deg))
        if lost:
            return WorldPose.invalid("dropped out (noisy_oracle)", object_name=frame.object_name)
        true = super().estimate(frame)
        true.position[:2] += dxy
        true.quaternion = quat_mul(quat_from_yaw(dyaw), true.quaternion)
        return true


def _is_real(value: object) -> bool:
    return isinstance(value, Real) and not isinstance(value, bool)


class OccludedOraclePoseSource(NoisyOraclePoseSource):
    """The noisy oracle, lost whenever the hand is near the object: a corruptor for training a
    policy that will act from an estimator's *held* estimate.

    An image estimator loses the object as the hand comes down over it (the gripper hides it
    from the camera) and keeps losing it while the object is in the hand, so the last estimate
    before the approach is held through the grasp and the lift (``pose_age`` grows, the
    object seen to stay on the table). A policy trained on the oracle never saw that: its
    object pose always followed the object. Here an estimate is lost (``valid=False``, so
    the wrapper holds the previous one) while the hand (``observation["ee_pos"]``) is within
    ``hide_distance_m`` of the object's centre; the distance is drawn per episode, uniformly
    from ``hide_distance_m = (low, high)``, because how close the hand comes before the view
    is lost depends on the object's size and the approach. Estimates that are made carry the
    noisy oracle's noise.
    """

    def __init__(
        self,
        pos_sigma_m: float = 0.005,
        yaw_sigma_deg: float = 5.0,
        dropout: float = 0.0,
        hide_distance_m: Sequence[float] = (0.06, 0.2),
    ) -> None:
        super().__init__(pos_sigma_m, yaw_sigma_deg, dropout)
        low_high = list(hide_distance_m) if isinstance(hide_distance_m, (list, tuple)) else []
        if not (
            len(low_high) == 2
            and all(_is_real(v) and np.isfinite(v) for v in low_high)
            and 0.0 <= low_high[0] <= low_high[1]
        ):
            raise ValueError(
                "hide_distance_m must be [low, high] in metres with 0 <= low <= high, got "
                f"{hide_distance_m!r}"
            )
        self.hide_distance_m = (float(low_high[0]), float(low_high[1]))
        self._hide = self.hide_distance_m[1]

    def reset(self, frame: PerceptionFrame, rng: np.random.Generator) -> None:
        super().reset(frame, rng)
        self._hide = float(rng.uniform(*self.hide_distance_m))

    def hidden(self, frame: PerceptionFrame) -> bool:
        """Whether the hand hides the object in this frame (this episode's distance)."""
        if "ee_pos" not in frame.observation:
            raise ValueError(
                "occluded_oracle needs the hand's position: the env's observation has no ee_pos"
            )
        ee = np.asarray(frame.observation["ee_pos"], float)
        obj = np.asarray(frame.truth["position"], float)
        return bool(np.linalg.norm(ee - obj) < self._hide)

    def estimate(self, frame: PerceptionFrame) -> WorldPose:
        est = super().estimate(frame)  # draws its noise either way: one stream per episode
        if self.hidden(frame):
            return WorldPose.invalid(
                "hidden by the hand (occluded_oracle)", object_name=frame.object_name
            )
        return est
