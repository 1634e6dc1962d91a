"""Object symmetry annotations, shared by the simulator catalogue and the pose metrics."""

from __future__ import annotations

import functools
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
        # Tuples of floats whatever sequences were passed: hashable (the rotation sets are
        # cached per symmetry) and equal by value.
        object.__setattr__(self, "axis", tuple(float(v) for v in self.axis))
        object.__setattr__(self, "flips", tuple(tuple(float(v) for v in f) for f in self.flips))
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
        toolkit does for its symmetry-aware error measures. Built once per symmetry and step
        (an axial set is 360 matrices, and pose scoring asks for it at every env step); the
        array is shared, hence read-only.
        """
        return _rotations(self, float(step_deg))


@functools.lru_cache(maxsize=256)
def _rotations(symmetry: Symmetry, step_deg: float) -> np.ndarray:
    axis = np.asarray(symmetry.axis, dtype=float)
    if symmetry.kind == "none":
        base = [np.eye(3)]
    elif symmetry.kind == "axial":
        n = max(1, int(round(360.0 / step_deg)))
        base = [_axis_angle(axis, 2 * np.pi * i / n) for i in range(n)]
    else:
        base = [_axis_angle(axis, 2 * np.pi * i / symmetry.order) for i in range(symmetry.order)]
    out = list(base)
    for flip in symmetry.flips:
        f = _axis_angle(np.asarray(flip, dtype=float), np.pi)
        out += [r @ f for r in base]
    rots = np.stack(out)
    rots.flags.writeable = False
    return rots
