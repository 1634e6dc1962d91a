"""The robot: servo/gripper interface to a simulation, and the arm's kinematics model."""

from scorbot_gym.robot.kinematics import (
    JOINT_HIGH,
    JOINT_LOW,
    ArmKinematics,
    HandGeometry,
    tool_pitch,
    wrap_half_turn,
)
from scorbot_gym.robot.servos import Robot

__all__ = [
    "JOINT_HIGH",
    "JOINT_LOW",
    "ArmKinematics",
    "HandGeometry",
    "Robot",
    "tool_pitch",
    "wrap_half_turn",
]
