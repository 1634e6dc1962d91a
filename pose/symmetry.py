"""Object symmetry annotations, shared by the simulator catalogue and the pose metrics."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

SymmetryKind = Literal["none", "axial", "discrete"]


def _axis_angle(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation matrix about a unit ``axis`` by ``angle`` radians (Rodrigues)."""
    x, y, z = axis
    k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + np.sin(angle) * k + (1.0 - np.cos(angle)) * (k @ k)


@dataclass(frozen=True)
class Symmetry:
    """Rotational symmetries of an object, in the object's own frame.

    ``kind="none"``: no symmetry. ``kind="axial"``: continuous rotation about ``axis`` (a can,
    a ball about its vertical axis). ``kind="discrete"``: ``order``-fold rotations about ``axis``
    (a square box seen from above has order 4), optionally combined with ``flips``: extra
    180-degree rotations about the given perpendicular axes (a box that looks the same upside down).
    """

    kind: SymmetryKind = "none"
    axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    order: int = 1
    flips: tuple[tuple[float, float, float], ...] = ()

    def __post_init__(self) -> None:
        if self.kind not in ("none", "axial", "discrete"):
            raise ValueError(
                f"symmetry kind must be 'none', 'axial' or 'discrete', got {self.kind!r}"
            )
        if self.kind == "discrete" and self.order < 1:
            raise ValueError(f"discrete symmetry needs order >= 1, got {self.order}")
        if not np.isclose(np.linalg.norm(self.axis), 1.0, atol=1e-6):
            raise ValueError(f"symmetry axis must be a unit vector, got {self.axis}")

    def rotations(self, step_deg: float = 1.0) -> np.ndarray:
        """All symmetry rotations as an ``(N, 3, 3)`` array; identity first.

        A continuous (axial) symmetry is discretized every ``step_deg`` degrees, as the BOP
        toolkit does for its symmetry-aware error measures.
        """
        axis = np.asarray(self.axis, dtype=float)
        if self.kind == "none":
            base = [np.eye(3)]
        elif self.kind == "axial":
            n = max(1, int(round(360.0 / step_deg)))
            base = [_axis_angle(axis, 2 * np.pi * i / n) for i in range(n)]
        else:
            base = [_axis_angle(axis, 2 * np.pi * i / self.order) for i in range(self.order)]
        out = list(base)
        for flip in self.flips:
            f = _axis_angle(np.asarray(flip, dtype=float), np.pi)
            out += [r @ f for r in base]
        return np.stack(out)
