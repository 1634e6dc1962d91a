"""The layout of a training run folder, and reading it back with one-line errors.

A run folder (``scorbot-gym train --out DIR``)::

    config.json        the TrainConfig, hyperparameters resolved
    hyperparams.yml    the resolved hyperparameters and how they map onto SB3 (read-only record)
    conf.yml           the user's --conf hyperparameter file, as given (if one was)
    monitor/           SB3 Monitor CSVs, one per env and segment (env_0.monitor.csv, ...;
                       a resumed run adds env_0.resume1.monitor.csv, ...), and
                       evaluations.npz (the evaluations, as SB3's EvalCallback writes them)
    checkpoint/        model.safetensors, replay_buffer.npz, vecnormalize.json, state.json
                       (formats that cannot run code: see scorbot_gym.rl.checkpoint); written
                       whole into .checkpoint.staging/, then swapped in (:func:`swap_in`)
    policy/            the last exported policy (model.safetensors, policy.json, normalize.npz)
    best/              the policy of the best evaluation so far (latest among equals)
    tb/                TensorBoard logs

    .scorbot-gym-run.json  the marker: this folder is a run this tool made (see :func:`claim`)
    .scorbot-gym-run.lock  locked (flock) by the process training or resuming the run

``--seeds 0,1,2`` makes one such folder per seed (``seed_0/``, ...) next to ``seeds.json``.
This module imports no SB3 or torch: the CLI and the rollout resolve folders with it.
"""

from __future__ import annotations

import contextlib
import datetime
import json
import os
import shutil
import socket
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from scorbot_gym.outputs import (
    OutputError,
    atomic_write_json,
    check_output_folder,
    exclusive_lock,
    refuse_if_locked,
)

CONFIG = "config.json"
HYPERPARAMS = "hyperparams.yml"
CONF = "conf.yml"
SEEDS = "seeds.json"
CHECKPOINT = "checkpoint"
#: a checkpoint being written, and the one it replaces while the two are swapped
STAGING_CHECKPOINT = ".checkpoint.staging"
PREVIOUS_CHECKPOINT = ".checkpoint.previous"
STATE = "state.json"
POLICY = "policy"
BEST = "best"
MONITOR = "monitor"
EVALUATIONS = "evaluations.npz"  # in MONITOR, beside the CSVs
TENSORBOARD = "tb"
#: what a run writes besides config.json (removed when a run that never checkpointed restarts)
ARTEFACTS = (HYPERPARAMS, CONF, MONITOR, CHECKPOINT, STAGING_CHECKPOINT, POLICY, BEST, TENSORBOARD)
CHECKPOINTS = ("best", "last")
MARKER = ".scorbot-gym-run.json"
LOCK = ".scorbot-gym-run.lock"


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
    """Whether ``run`` has a checkpoint (one that a killed swap left aside included)."""
    run = Path(run)
    return (run / CHECKPOINT / STATE).is_file() or (run / PREVIOUS_CHECKPOINT / STATE).is_file()


def swap_in(run: Path) -> None:
    """Make the complete checkpoint in ``run/.checkpoint.staging`` the run's ``checkpoint/``.

    Its files (weights, optimisers, replay buffer, state) must describe one moment of the
    run: written one by one into ``checkpoint/``, a kill between two of them left weights
    ahead of their state. Two renames and a delete instead; a kill between any two of them
    leaves either folder whole, which :func:`settle_checkpoint` puts back in place.
    """
    run = Path(run)
    ck, staging, previous = run / CHECKPOINT, run / STAGING_CHECKPOINT, run / PREVIOUS_CHECKPOINT
    if previous.exists():  # a swap killed after its second rename
        shutil.rmtree(previous)
    if ck.exists():
        os.replace(ck, previous)
    os.replace(staging, ck)
    shutil.rmtree(previous, ignore_errors=True)


def settle_checkpoint(run: Path) -> None:
    """After a kill during a checkpoint's write or swap (:func:`swap_in`), leave ``run`` with
    its newest complete checkpoint as ``checkpoint/``: a staging folder whose ``state.json``
    (written last) is there is swapped in, an unfinished one removed; a checkpoint that an
    unfinished swap set aside is put back or, once its successor is in place, removed. Call
    it holding the run's lock."""
    run = Path(run)
    ck, staging, previous = run / CHECKPOINT, run / STAGING_CHECKPOINT, run / PREVIOUS_CHECKPOINT
    if (staging / STATE).is_file():
        swap_in(run)
        return
    if staging.exists():
        shutil.rmtree(staging)
    if previous.exists():
        if ck.exists():
            shutil.rmtree(previous)
        else:
            os.replace(previous, ck)


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


def is_own_run(folder: Path) -> bool:
    """Whether ``folder`` carries the marker a run of this tool writes before anything else."""
    return (Path(folder) / MARKER).is_file()


def check_new_run_folder(out: str | Path) -> Path:
    """``out`` as the folder of a new run, checked without writing anything: a folder that can
    be made or written, and missing, empty, or one of this tool's own runs that stopped before
    its first checkpoint; anything else is a one-line :class:`OutputError` naming what is
    there."""
    out = check_output_folder(out, "--out")
    refuse_if_locked(out / LOCK, f"run folder {out}")  # a run training now: say so first
    _refuse_unless_claimable(out)
    return out


def _refuse_unless_claimable(out: Path) -> None:
    if not out.is_dir():
        return
    present = sorted(set(os.listdir(out)) - {LOCK})
    if not present:
        return
    if not is_own_run(out):
        shown = ", ".join(present[:4]) + (", ..." if len(present) > 4 else "")
        raise OutputError(
            f"--out {out} is not empty and not a scorbot-gym run ({shown}); nothing in it "
            "is touched: train into a new or empty folder"
        )
    if has_checkpoint(out) or (out / SEEDS).is_file() or seed_runs(out):
        raise OutputError(f"--out {out} already holds a run; resume it with --resume {out}")


@contextlib.contextmanager
def claim(out: str | Path, *, new: bool) -> Iterator[Path]:
    """Hold the run folder ``out`` for the ``with`` body: the only process training into it.

    ``new``: ``out`` must be missing, empty, or a run of this tool (its :data:`MARKER`) that
    stopped before its first checkpoint, whose files (:data:`ARTEFACTS`, ``config.json``) are
    removed; nothing this tool did not write is ever deleted. The marker is written first.
    Otherwise (resuming) ``out`` must be a run folder. Either way the folder's :data:`LOCK` is
    held (``flock``) until the body ends, so a second ``train --out``/``--resume`` of the same
    folder is refused in one line rather than overwriting the first.
    """
    out = Path(out)
    if new:
        check_new_run_folder(out)  # before anything is written into the folder
        out.mkdir(parents=True, exist_ok=True)
    else:
        if not out.is_dir():
            raise FileNotFoundError(f"cannot resume {out}: no such run folder")
        if not ((out / CONFIG).is_file() or (out / SEEDS).is_file()):
            raise FileNotFoundError(f"cannot resume {out}: {CONFIG} is missing (not a run folder)")
        check_output_folder(out, "--resume")
    with exclusive_lock(out / LOCK, f"run folder {out}"):
        if new:
            _refuse_unless_claimable(out)  # another run may have finished in between
            if is_own_run(out):
                for name in (*ARTEFACTS, CONFIG):
                    target = out / name
                    if target.is_dir() and not target.is_symlink():
                        shutil.rmtree(target)
                    elif target.exists() or target.is_symlink():
                        target.unlink()
            atomic_write_json(
                out / MARKER,
                {
                    "written_by": "scorbot-gym train",
                    "created": datetime.datetime.now(datetime.timezone.utc).isoformat(),
                    "host": socket.gethostname(),
                    "pid": os.getpid(),
                },
            )
        yield out


__all__ = [
    "ARTEFACTS",
    "BEST",
    "CHECKPOINT",
    "PREVIOUS_CHECKPOINT",
    "STAGING_CHECKPOINT",
    "CONF",
    "CONFIG",
    "EVALUATIONS",
    "HYPERPARAMS",
    "LOCK",
    "MARKER",
    "MONITOR",
    "POLICY",
    "SEEDS",
    "STATE",
    "check_new_run_folder",
    "claim",
    "has_checkpoint",
    "settle_checkpoint",
    "swap_in",
    "is_own_run",
    "policy_dir",
    "read_json",
    "seed_runs",
]
