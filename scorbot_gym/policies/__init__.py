"""Policies on observations: the protocol, the scripted PBVS controller, a random policy, and
trained stable-baselines3 models (``SB3Policy``)."""

from scorbot_gym.policies.base import Policy
from scorbot_gym.policies.random import RandomPolicy
from scorbot_gym.policies.sb3 import SHIPPED_POLICY, SB3Policy
from scorbot_gym.policies.scripted import ScriptedGraspPolicy, observed_pose, yaw_from_quat

__all__ = [
    "SHIPPED_POLICY",
    "Policy",
    "RandomPolicy",
    "SB3Policy",
    "ScriptedGraspPolicy",
    "observed_pose",
    "yaw_from_quat",
]
