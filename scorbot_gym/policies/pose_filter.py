"""A gated running average of grasp estimates, for position-based visual servoing.

Re-planning from every raw estimate makes the arm chase the estimator's noise: with 10 deg of
heading noise it never settles (the descent restarts whenever the goal jumps). Averaging alone
would make it blind to a real move. The filter separates the two the way a tracker's
innovation gate does: an estimate close to the current belief (within ``gate_m`` and
``gate_rad``) is averaged in (a running mean over the last ``window`` accepted estimates); an
estimate outside the gate is held as a candidate, and ``confirm`` consecutive candidates that
agree with each other mean the object really moved: the belief restarts from them.

It works on what the controller needs, the grasp point and the closing yaw of a two-finger
gripper, which is only defined modulo a half turn.
"""

from __future__ import annotations

import numpy as np

from scorbot_gym.robot.kinematics import wrap_half_turn


class GraspPoseFilter:
    """Filtered grasp point (3) and closing yaw (rad, modulo pi)."""

    def __init__(
        self, gate_m: float = 0.02, gate_rad: float = 0.35, window: int = 8, confirm: int = 3
    ) -> None:
        if not (gate_m > 0 and gate_rad > 0):
            raise ValueError(f"gates must be > 0, got gate_m={gate_m}, gate_rad={gate_rad}")
        if window < 1 or confirm < 1:
            raise ValueError(f"window and confirm must be >= 1, got {window}, {confirm}")
        self.gate_m, self.gate_rad = gate_m, gate_rad
        self.window, self.confirm = window, confirm
        self.reset()

    def reset(self) -> None:
        self.point: np.ndarray | None = None
        self.yaw = 0.0
        self._n = 0
        self._candidates: list[tuple[np.ndarray, float]] = []
        self.restarts = 0

    def _inside(self, point: np.ndarray, yaw: float, ref_point: np.ndarray, ref_yaw: float) -> bool:
        return bool(
            np.linalg.norm(point[:2] - ref_point[:2]) <= self.gate_m
            and abs(wrap_half_turn(yaw - ref_yaw)) <= self.gate_rad
        )

    def update(self, point: np.ndarray, yaw: float) -> bool:
        """Take one estimate; True if the belief restarted (the object moved)."""
        point = np.asarray(point, dtype=float)
        if self.point is None:
            self._restart(point, yaw)
            return True
        if self._inside(point, yaw, self.point, self.yaw):
            self._candidates.clear()
            self._n = min(self._n + 1, self.window)
            self.point = self.point + (point - self.point) / self._n
            self.yaw = self.yaw + wrap_half_turn(yaw - self.yaw) / self._n
            return False
        if self._candidates and not self._inside(point, yaw, *self._candidates[-1]):
            self._candidates.clear()  # outliers that disagree with each other: noise
        self._candidates.append((point, yaw))
        if len(self._candidates) >= self.confirm:
            pts = np.array([p for p, _ in self._candidates])
            ref = self._candidates[-1][1]
            yaws = [ref + wrap_half_turn(y - ref) for _, y in self._candidates]
            self._restart(pts.mean(axis=0), float(np.mean(yaws)))
            self.restarts += 1
            return True
        return False

    def _restart(self, point: np.ndarray, yaw: float) -> None:
        self.point, self.yaw, self._n = point.copy(), float(yaw), 1
        self._candidates.clear()
