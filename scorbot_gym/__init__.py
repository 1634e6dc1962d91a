"""scorbot-gym: a simulated SCORBOT-ER Vplus tabletop for vision-based grasping.

Importing the package registers the Gymnasium ids ``ScorbotGrasp-v0`` (joint actions) and
``ScorbotGraspCartesian-v0`` (Cartesian actions); ``gym.make("scorbot_gym:ScorbotGrasp-v0")``
imports it for you.

The simulator (MuJoCo, dm_control) and the vector envs are imported on first use of the names
below, not by the package import: the registration needs Gymnasium only, and the command line's
``--help`` and argument errors should not pay a second of imports.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from scorbot_gym import _gl

_gl.choose_backend()

from scorbot_gym.envs import ENV_IDS, register_envs  # noqa: E402  (Gymnasium only)

register_envs()

if TYPE_CHECKING:
    from scorbot_gym.envs.factory import make_env
    from scorbot_gym.envs.grasp import ScorbotGraspEnv
    from scorbot_gym.envs.overlapped import OverlappedVectorEnv
    from scorbot_gym.envs.vector import pin_env_fns
    from scorbot_gym.envs.worker import WatchedAsyncVectorEnv

__version__ = "0.1.0"
__all__ = [
    "ENV_IDS",
    "OverlappedVectorEnv",
    "ScorbotGraspEnv",
    "WatchedAsyncVectorEnv",
    "make_env",
    "pin_env_fns",
    "register_envs",
]

# Public name -> the module that defines it, imported when the name is first used.
_LAZY = {
    "ScorbotGraspEnv": "scorbot_gym.envs.grasp",
    "make_env": "scorbot_gym.envs.factory",
    "OverlappedVectorEnv": "scorbot_gym.envs.overlapped",
    "pin_env_fns": "scorbot_gym.envs.vector",
    "WatchedAsyncVectorEnv": "scorbot_gym.envs.worker",
}


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'scorbot_gym' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY})
