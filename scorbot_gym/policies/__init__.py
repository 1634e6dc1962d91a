"""Policies on observations: the protocol, the scripted PBVS controller, a random policy."""

from scorbot_gym.policies.base import Policy
from scorbot_gym.policies.random import RandomPolicy
from scorbot_gym.policies.scripted import ScriptedGraspPolicy, observed_pose, yaw_from_quat

__all__ = ["Policy", "RandomPolicy", "ScriptedGraspPolicy", "observed_pose", "yaw_from_quat"]
