"""Object disturbances: what makes servoing matter.

A controller that estimates the pose once and then plays a fixed plan grasps a static object as
well as one that re-estimates. These disturbances move the object while the arm approaches, so
only a controller that follows new estimates can succeed:

- :class:`ObjectPush`: once per episode, at a seeded random step before the grasp, the object is
  pushed a few centimetres in a random direction and turned about the vertical (a person nudging
  it, or a conveyor jolt);
- :class:`ObjectSlide`: the object slides slowly and steadily across the table (and turns) until
  the robot first touches it.

Both act only while the robot does not touch the object and it has not been lifted, keep the
object inside the workspace, and draw every random choice from the episode's seeded generator.
What happened is reported in ``info["disturbance"]`` (ground truth, for scoring only).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from scorbot_gym.sim.simulation import Simulation, quat_from_yaw, quat_mul


class Disturbance(Protocol):
    """Moves the object during an episode; ``apply`` runs after every control step."""

    name: str

    def reset(self, rng: np.random.Generator) -> None: ...

    def apply(self, sim: Simulation, step: int, dt: float, touched: bool) -> dict[str, Any]: ...


def _move_object(sim: Simulation, shift_xy: np.ndarray, turn: float) -> np.ndarray:
    """Translate the object in the table plane and turn it about world z; returns the shift that
    was actually applied (clipped so the object stays inside the workspace)."""
    pos, quat = sim.object_pose()
    (x0, x1), (y0, y1) = sim.workspace_xy_bounds
    new_xy = np.clip(pos[:2] + shift_xy, [x0, y0], [x1, y1])
    new_pos = np.r_[new_xy, pos[2]]
    sim.set_object_pose(new_pos, quat_mul(quat_from_yaw(turn), quat))
    sim.forward()
    return new_xy - pos[:2]


def _check_range(name: str, lo_hi: tuple[float, float], low: float = 0.0) -> tuple[float, float]:
    lo, hi = (float(v) for v in lo_hi)
    if not (np.isfinite(lo) and np.isfinite(hi) and low <= lo <= hi):
        raise ValueError(
            f"{name} must be a finite (low, high) with {low} <= low <= high, got {lo_hi}"
        )
    return lo, hi


@dataclass
class ObjectPush:
    """One push of ``distance_m`` (uniform in the range) in a random direction plus a turn of
    ``turn_deg`` (uniform magnitude, random sign), at a step drawn uniformly from ``steps``.

    The default window (steps 8-30 at 25 Hz) falls in the scripted controller's approach and
    early descent, after it has planned from its first estimate."""

    distance_m: tuple[float, float] = (0.02, 0.05)
    turn_deg: tuple[float, float] = (15.0, 45.0)
    steps: tuple[int, int] = (8, 30)
    name: str = field(default="push", init=False)

    def __post_init__(self) -> None:
        self.distance_m = _check_range("distance_m", self.distance_m)
        self.turn_deg = _check_range("turn_deg", self.turn_deg)
        lo, hi = self.steps
        if int(lo) != lo or int(hi) != hi or not 1 <= lo <= hi:
            raise ValueError(
                f"steps must be integers (low, high) with 1 <= low <= high, got {self.steps}"
            )
        self._plan: dict[str, Any] | None = None

    def reset(self, rng: np.random.Generator) -> None:
        heading = rng.uniform(-np.pi, np.pi)
        self._plan = {
            "step": int(rng.integers(self.steps[0], self.steps[1] + 1)),
            "shift": rng.uniform(*self.distance_m) * np.array([np.cos(heading), np.sin(heading)]),
            "turn": np.deg2rad(rng.uniform(*self.turn_deg)) * rng.choice([-1.0, 1.0]),
            "done": False,
        }

    def apply(self, sim: Simulation, step: int, dt: float, touched: bool) -> dict[str, Any]:
        plan = self._plan
        if plan is None:
            raise RuntimeError("ObjectPush.apply() before reset()")
        if not plan["done"] and step >= plan["step"]:
            plan["done"] = True
            if touched:  # the robot already holds or touches it: a push now is not a nudge
                plan["skipped"] = True
            else:
                plan["applied_shift"] = _move_object(sim, plan["shift"], plan["turn"])
                plan["applied_at"] = step
        return {
            "kind": self.name,
            "step": plan["step"],
            "applied": "applied_at" in plan,
            "shift_m": float(np.linalg.norm(plan.get("applied_shift", np.zeros(2)))),
            "turn_deg": float(np.rad2deg(plan["turn"])) if "applied_at" in plan else 0.0,
        }


@dataclass
class ObjectSlide:
    """Steady slide at ``speed_m_s`` (uniform in the range) in a random direction, turning at
    ``turn_deg_s`` (random sign), from the first step until the robot first touches it."""

    speed_m_s: tuple[float, float] = (0.005, 0.015)
    turn_deg_s: tuple[float, float] = (0.0, 10.0)
    name: str = field(default="slide", init=False)

    def __post_init__(self) -> None:
        self.speed_m_s = _check_range("speed_m_s", self.speed_m_s)
        self.turn_deg_s = _check_range("turn_deg_s", self.turn_deg_s)
        self._state: dict[str, Any] | None = None

    def reset(self, rng: np.random.Generator) -> None:
        heading = rng.uniform(-np.pi, np.pi)
        self._state = {
            "velocity": rng.uniform(*self.speed_m_s) * np.array([np.cos(heading), np.sin(heading)]),
            "turn_rate": np.deg2rad(rng.uniform(*self.turn_deg_s)) * rng.choice([-1.0, 1.0]),
            "stopped": False,
            "travelled": 0.0,
        }

    def apply(self, sim: Simulation, step: int, dt: float, touched: bool) -> dict[str, Any]:
        st = self._state
        if st is None:
            raise RuntimeError("ObjectSlide.apply() before reset()")
        st["stopped"] |= touched
        if not st["stopped"]:
            moved = _move_object(sim, st["velocity"] * dt, st["turn_rate"] * dt)
            st["travelled"] += float(np.linalg.norm(moved))
        return {"kind": self.name, "sliding": not st["stopped"], "travelled_m": st["travelled"]}


DISTURBANCES = {"push": ObjectPush, "slide": ObjectSlide}


def make_disturbance(spec: str | Disturbance | None) -> Disturbance | None:
    """``None``, a name (``"push"``, ``"slide"``) with default parameters, or an object."""
    if spec is None or spec == "none":
        return None
    if isinstance(spec, str):
        if spec not in DISTURBANCES:
            raise ValueError(
                f"unknown disturbance {spec!r}; valid: none, {', '.join(DISTURBANCES)} "
                "or a Disturbance object"
            )
        return DISTURBANCES[spec]()
    if not (hasattr(spec, "reset") and hasattr(spec, "apply")):
        raise ValueError(f"disturbance must be None, a name or a Disturbance object, got {spec!r}")
    return spec
