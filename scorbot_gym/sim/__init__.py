"""Simulation layer: MJCF pieces (arm, arena, objects, cameras) and a thin MuJoCo facade."""

from scorbot_gym.sim.simulation import Simulation

__all__ = ["Simulation"]
