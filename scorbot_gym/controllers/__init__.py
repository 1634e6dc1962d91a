"""Grasping controllers."""

from scorbot_gym.controllers.scripted import ObjectPose2D, ScriptedGraspController

__all__ = ["ObjectPose2D", "ScriptedGraspController"]
