"""The layout of a training run folder, and reading it back with one-line errors.

A run folder (``scorbot-gym train --out DIR``)::

    config.json        the TrainConfig, hyperparameters resolved
    hyperparams.yml    the resolved hyperparameters and how they map onto SB3 (read-only record)
    conf.yml           the user's --conf hyperparameter file, as given (if one was)
    monitor/           SB3 Monitor CSVs, one per env and segment (env_0.monitor.csv, ...;
                       a resumed run adds env_0.resume1.monitor.csv, ...), and
                       evaluations.npz (the evaluations, as SB3's EvalCallback writes them)
    checkpoint/        model.zip, replay_buffer.pkl, vecnormalize.pkl, state.json
    policy/            the last exported policy (model.zip, policy.json, normalize.npz)
    best/              the policy of the best evaluation so far (latest among equals)
    tb/                TensorBoard logs

``--seeds 0,1,2`` makes one such folder per seed (``seed_0/``, ...) next to ``seeds.json``.
This module imports no SB3 or torch: the CLI and the rollout resolve folders with it.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

CONFIG = "config.json"
HYPERPARAMS = "hyperparams.yml"
CONF = "conf.yml"
SEEDS = "seeds.json"
CHECKPOINT = "checkpoint"
STATE = "state.json"
POLICY = "policy"
BEST = "best"
MONITOR = "monitor"
EVALUATIONS = "evaluations.npz"  # in MONITOR, beside the CSVs
TENSORBOARD = "tb"
#: what a run writes besides config.json (removed when a run that never checkpointed restarts)
ARTEFACTS = (HYPERPARAMS, CONF, MONITOR, CHECKPOINT, POLICY, BEST, TENSORBOARD)
CHECKPOINTS = ("best", "last")


def read_json(path: Path, what: str = "a JSON object") -> dict[str, Any]:
    """The JSON object in ``path``; a one-line error naming the file if it is not one."""
    try:
        data = json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise FileNotFoundError(f"{path} is missing") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path} is not valid JSON ({exc})") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path} must hold {what}, got {type(data).__name__}")
    return data


def has_checkpoint(run: Path) -> bool:
    return (Path(run) / CHECKPOINT / STATE).is_file()


def seed_runs(folder: Path) -> list[Path]:
    """The per-seed run folders of a ``--seeds`` folder, in seed order ([] for a single run)."""
    folder = Path(folder)
    runs = [p for p in folder.glob("seed_*") if p.is_dir() and p.name[5:].isdigit()]
    return sorted(runs, key=lambda p: int(p.name[5:]))


def policy_dir(path: str | Path, checkpoint: str = "best") -> Path:
    """The policy folder to load for ``path``: a policy folder itself, or a run folder's
    ``best/`` (``checkpoint="best"``, falling back to the last policy if no evaluation has
    been exported yet) or ``policy/`` (``"last"``)."""
    if checkpoint not in CHECKPOINTS:
        raise ValueError(f"checkpoint must be one of {CHECKPOINTS}, got {checkpoint!r}")
    path = Path(path)
    if (path / "policy.json").is_file():
        return path
    if not path.is_dir():
        raise FileNotFoundError(f"no policy or training run folder at {path}")
    seeds = seed_runs(path)
    if seeds and not (path / CONFIG).is_file():
        names = ", ".join(p.name for p in seeds)
        raise ValueError(f"{path} holds runs of several seeds ({names}): pass one of them")
    order = (BEST, POLICY) if checkpoint == "best" else (POLICY,)
    for name in order:
        if (path / name / "policy.json").is_file():
            return path / name
    raise FileNotFoundError(
        f"{path} holds neither a policy (policy.json) nor an exported one in a training run "
        f"({'/ or '.join(order)}/)"
    )


__all__ = [
    "ARTEFACTS",
    "BEST",
    "CHECKPOINT",
    "CONF",
    "CONFIG",
    "EVALUATIONS",
    "HYPERPARAMS",
    "MONITOR",
    "POLICY",
    "SEEDS",
    "STATE",
    "has_checkpoint",
    "policy_dir",
    "read_json",
    "seed_runs",
]
