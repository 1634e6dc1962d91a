"""Privileged pose sources: the ground truth, and the ground truth corrupted on purpose.

``NoisyOraclePoseSource`` is dm_control's *corruptor* idea applied to the pose: controlled,
seeded noise and dropout on top of the truth, so that a policy's robustness can be plotted
against one knob at a time instead of against a whole estimator's error profile.
"""

from __future__ import annotations

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
