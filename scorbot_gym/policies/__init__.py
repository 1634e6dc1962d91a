"""Policies on observations: the protocol, the scripted PBVS controller, a random policy,
trained stable-baselines3 models (``SB3Policy``) and the stand-alone imitation policy
(``ImitationPolicy``); ``load_policy`` opens any saved policy folder."""

from scorbot_gym.policies.base import Policy
from scorbot_gym.policies.imitation import SHIPPED_LEARNED_POLICY, ImitationPolicy
from scorbot_gym.policies.loading import load_policy, uses_scripted_controller
from scorbot_gym.policies.random import RandomPolicy
from scorbot_gym.policies.sb3 import SHIPPED_POLICY, SB3Policy
from scorbot_gym.policies.scripted import ScriptedGraspPolicy, observed_pose, yaw_from_quat

__all__ = [
    "SHIPPED_LEARNED_POLICY",
    "SHIPPED_POLICY",
    "ImitationPolicy",
    "Policy",
    "RandomPolicy",
    "SB3Policy",
    "ScriptedGraspPolicy",
    "load_policy",
    "observed_pose",
    "uses_scripted_controller",
    "yaw_from_quat",
]
