"""Learned grasping: SB3 training runs with YAML hyperparameters, a residual wrapper around the
scripted controller, scripted demonstrations and behaviour cloning, training callbacks and
learning curves.

Names are imported on first use (PEP 562), so that ``scorbot_gym.rl.hyperparams`` and
``scorbot_gym.rl.runs`` (what the CLI needs to parse arguments) do not pull in SB3 and torch.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "ALGOS": "scorbot_gym.rl.hyperparams",
    "POSES": "scorbot_gym.rl.hyperparams",
    "ResidualActionWrapper": "scorbot_gym.rl.residual",
    "residual_action": "scorbot_gym.rl.residual",
    "TrainConfig": "scorbot_gym.rl.training",
    "resume": "scorbot_gym.rl.training",
    "train": "scorbot_gym.rl.training",
    "train_seeds": "scorbot_gym.rl.training",
    "learning_curves": "scorbot_gym.rl.curves",
}


def __getattr__(name: str) -> Any:
    if name not in _EXPORTS:
        raise AttributeError(f"module 'scorbot_gym.rl' has no attribute {name!r}")
    return getattr(importlib.import_module(_EXPORTS[name]), name)


def __dir__() -> list[str]:
    return sorted(list(globals()) + list(_EXPORTS))


__all__ = sorted(_EXPORTS)
