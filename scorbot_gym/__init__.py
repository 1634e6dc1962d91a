"""scorbot-gym: a simulated SCORBOT-ER Vplus tabletop for vision-based grasping.

Importing the package registers the Gymnasium ids ``ScorbotGrasp-v0`` (joint actions) and
``ScorbotGraspCartesian-v0`` (Cartesian actions); ``gym.make("scorbot_gym:ScorbotGrasp-v0")``
imports it for you.
"""

from scorbot_gym import _gl

_gl.choose_backend()
_gl.import_mjcf()

from scorbot_gym.envs import ENV_IDS, ScorbotGraspEnv, register_envs  # noqa: E402

register_envs()

from scorbot_gym.envs.factory import make_env  # noqa: E402
from scorbot_gym.envs.overlapped import OverlappedVectorEnv  # noqa: E402
from scorbot_gym.envs.vector import pin_env_fns  # noqa: E402

__version__ = "0.1.0"
__all__ = [
    "ENV_IDS",
    "OverlappedVectorEnv",
    "ScorbotGraspEnv",
    "make_env",
    "pin_env_fns",
    "register_envs",
]
