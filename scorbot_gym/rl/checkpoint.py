"""A training checkpoint's files, in formats that cannot run code.

``checkpoint/`` of a run folder holds (written together into a staging folder by
:class:`~scorbot_gym.rl.training._Run`, then swapped in by :func:`scorbot_gym.rl.runs.swap_in`):

- ``model.safetensors``: the algorithm with its optimisers and counters
  (:func:`scorbot_gym.policies.sb3_files.save_model` with ``training=True``);
- ``replay_buffer.npz``: the filled rows of the replay buffer (and a fine-tune's demonstration
  buffer), read with ``allow_pickle=False``; its layout is a JSON string in the file;
- ``vecnormalize.json``: ``VecNormalize``'s running means, variances and counts and its settings;
- ``state.json``: timesteps, wall time, evaluations, configuration.

SB3's own ``save_replay_buffer`` and ``VecNormalize.save`` are pickles: a run folder someone
handed you would run its code on ``--resume``. Older run folders hold those files
(:data:`OLD_FILES`) and are refused, naming ``scorbot-gym convert``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from pose.fileio import atomic_write_json

MODEL = "model.safetensors"
REPLAY_BUFFER = "replay_buffer.npz"
VEC_NORMALIZE = "vecnormalize.json"
#: what the pickle-based format wrote instead of each file above
OLD_FILES = {
    MODEL: "model.zip",
    REPLAY_BUFFER: "replay_buffer.pkl",
    VEC_NORMALIZE: "vecnormalize.pkl",
}
BUFFER_FORMAT = "scorbot-gym-replay-buffer"
NORMALIZE_FORMAT = "scorbot-gym-vecnormalize"
VERSION = 1
_FIELDS = ("observations", "next_observations", "actions", "rewards", "dones", "timeouts")


# --- replay buffer ---------------------------------------------------------------------------
def _rows(buffer) -> int:
    """The rows that hold transitions (all of them once the buffer has wrapped around; all of
    them too when the next observation is the following row, ``optimize_memory_usage``)."""
    if buffer.full or getattr(buffer, "optimize_memory_usage", False):
        return buffer.buffer_size
    return buffer.pos


def _buffer_arrays(buffer, prefix: str, arrays: dict[str, np.ndarray]) -> dict[str, Any]:
    n = _rows(buffer)
    for field in _FIELDS:
        value = getattr(buffer, field, None)
        if isinstance(value, dict):
            arrays.update({f"{prefix}{field}/{k}": v[:n] for k, v in value.items()})
        elif isinstance(value, np.ndarray):
            arrays[f"{prefix}{field}"] = value[:n]
    return {
        "class": type(buffer).__name__,
        "buffer_size": int(buffer.buffer_size),
        "n_envs": int(buffer.n_envs),
        "pos": int(buffer.pos),
        "full": bool(buffer.full),
        "rows": n,
    }


def save_replay_buffer(buffer, path: str | Path) -> None:
    """The buffer's filled rows as ``.npz`` (a fine-tune's demonstrations under ``demos/``)."""
    arrays: dict[str, np.ndarray] = {}
    layout = _buffer_arrays(buffer, "", arrays)
    demos = getattr(buffer, "demos", None)
    if demos is not None:
        layout["demos"] = _buffer_arrays(demos, "demos/", arrays)
    if hasattr(buffer, "demo_rows_drawn"):
        layout["demo_rows_drawn"] = int(buffer.demo_rows_drawn)
    layout.update(format=BUFFER_FORMAT, version=VERSION)
    np.savez(path, layout=np.array(json.dumps(layout)), **arrays)


def _fill(buffer, z, prefix: str, layout: dict[str, Any], path: Path) -> None:
    if layout.get("class") != type(buffer).__name__:
        raise ValueError(f"holds a {layout.get('class')!r}, the run uses {type(buffer).__name__}")
    for key in ("buffer_size", "n_envs"):
        if layout.get(key) != getattr(buffer, key):
            raise ValueError(
                f"{key} {layout.get(key)!r} differs from the run's {getattr(buffer, key)}"
            )
    n, pos = layout.get("rows"), layout.get("pos")
    if not (isinstance(n, int) and isinstance(pos, int) and 0 <= pos < buffer.buffer_size):
        raise ValueError(f"rows {n!r} / pos {pos!r} are not positions in the buffer")
    for field in _FIELDS:
        target = getattr(buffer, field, None)
        targets = target if isinstance(target, dict) else {"": target}
        for k, dest in targets.items():
            if not isinstance(dest, np.ndarray):
                continue
            key = f"{prefix}{field}/{k}" if k else f"{prefix}{field}"
            if key not in z.files:
                raise ValueError(f"{key} is missing")
            src = z[key]
            if src.shape != (n, *dest.shape[1:]) or n > len(dest):
                raise ValueError(
                    f"{key} has shape {src.shape}, the buffer takes {n} rows of {dest.shape[1:]}"
                )
            dest[:n] = src
    buffer.pos, buffer.full = pos, bool(layout.get("full"))


def load_replay_buffer(buffer, path: str | Path) -> None:
    """Fill ``buffer`` (the run's, freshly built) from ``path``; ``ValueError`` naming the file
    if it is damaged or of another buffer."""
    from stable_baselines3.common.buffers import ReplayBuffer

    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            layout = json.loads(str(z["layout"]))
            if not isinstance(layout, dict) or layout.get("format") != BUFFER_FORMAT:
                raise ValueError("not a scorbot-gym replay buffer")
            if layout.get("version") != VERSION:
                raise ValueError(f"format version {layout.get('version')!r}, this reads {VERSION}")
            _fill(buffer, z, "", layout, path)
            if isinstance(layout.get("demos"), dict) and hasattr(buffer, "demos"):
                demos = ReplayBuffer(
                    layout["demos"].get("buffer_size", 0),
                    buffer.observation_space,
                    buffer.action_space,
                    device=buffer.device,  # its samples join the online buffer's batches
                    n_envs=1,
                    handle_timeout_termination=False,
                )
                _fill(demos, z, "demos/", layout["demos"], path)
                buffer.demos = demos
                buffer.demo_rows_drawn = int(layout.get("demo_rows_drawn", 0))
    except Exception as exc:  # zip, npy, JSON and key errors of a damaged or foreign file
        msg = str(exc).splitlines()[0] if str(exc) else ""
        raise ValueError(
            f"cannot resume: {path} is damaged or not a replay buffer ({type(exc).__name__}: {msg})"
        ) from None


# --- VecNormalize ----------------------------------------------------------------------------
def _stats(rms) -> dict[str, Any]:
    return {
        "mean": np.asarray(rms.mean).tolist(),
        "var": np.asarray(rms.var).tolist(),
        "count": float(rms.count),
    }


def save_vec_normalize(venv, path: str | Path) -> None:
    """``VecNormalize``'s statistics and settings as JSON."""
    obs = venv.obs_rms
    atomic_write_json(
        path,
        {
            "format": NORMALIZE_FORMAT,
            "version": VERSION,
            "obs_rms": {k: _stats(r) for k, r in obs.items()}
            if isinstance(obs, dict)
            else _stats(obs),
            "ret_rms": _stats(venv.ret_rms),
            "norm_obs_keys": list(venv.norm_obs_keys) if venv.norm_obs_keys else None,
            "norm_obs": bool(venv.norm_obs),
            "norm_reward": bool(venv.norm_reward),
            "clip_obs": float(venv.clip_obs),
            "clip_reward": float(venv.clip_reward),
            "gamma": float(venv.gamma),
            "epsilon": float(venv.epsilon),
        },
    )


def _set_stats(rms, data: Any, what: str) -> None:
    if not isinstance(data, dict):
        raise ValueError(f"{what} must be an object with mean, var and count")
    mean = np.asarray(data.get("mean"), np.float64)
    var = np.asarray(data.get("var"), np.float64)
    count = data.get("count")
    if mean.shape != np.shape(rms.mean) or var.shape != np.shape(rms.var):
        raise ValueError(f"{what} has shape {mean.shape}, the run's is {np.shape(rms.mean)}")
    if not (isinstance(count, (int, float)) and math.isfinite(count) and count > 0):
        raise ValueError(f"{what}: count must be a number > 0, got {count!r}")
    if not (np.isfinite(mean).all() and np.isfinite(var).all() and (var >= 0).all()):
        raise ValueError(f"{what}: mean and var must be finite, var >= 0")
    rms.mean, rms.var, rms.count = mean, var, float(count)


def load_vec_normalize(venv, path: str | Path) -> None:
    """Set the run's fresh ``VecNormalize`` to the statistics in ``path`` (its settings must be
    the run's); ``ValueError`` naming the file otherwise."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
        if not isinstance(data, dict) or data.get("format") != NORMALIZE_FORMAT:
            raise ValueError("not scorbot-gym VecNormalize statistics")
        if data.get("version") != VERSION:
            raise ValueError(f"format version {data.get('version')!r}, this reads {VERSION}")
        keys = list(venv.norm_obs_keys) if venv.norm_obs_keys else None
        if data.get("norm_obs_keys") != keys:
            raise ValueError(f"it normalises {data.get('norm_obs_keys')}, the run {keys}")
        if isinstance(venv.obs_rms, dict):
            stored = data.get("obs_rms")
            if not isinstance(stored, dict) or set(stored) != set(venv.obs_rms):
                raise ValueError(f"obs_rms must have the entries {sorted(venv.obs_rms)}")
            for k, rms in venv.obs_rms.items():
                _set_stats(rms, stored[k], f"obs_rms[{k!r}]")
        else:
            _set_stats(venv.obs_rms, data.get("obs_rms"), "obs_rms")
        _set_stats(venv.ret_rms, data.get("ret_rms"), "ret_rms")
        for key in ("clip_obs", "clip_reward", "gamma", "epsilon"):
            value = data.get(key)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0:
                raise ValueError(f"{key} must be a number > 0, got {value!r}")
            setattr(venv, key, float(value))
        for key in ("norm_obs", "norm_reward"):
            if not isinstance(data.get(key), bool):
                raise ValueError(f"{key} must be true or false")
            setattr(venv, key, data[key])
    except (ValueError, UnicodeDecodeError, OSError) as exc:
        raise ValueError(
            f"cannot resume: {path} is damaged or not VecNormalize statistics ({exc})"
        ) from None


__all__ = [
    "MODEL",
    "OLD_FILES",
    "REPLAY_BUFFER",
    "VEC_NORMALIZE",
    "load_replay_buffer",
    "load_vec_normalize",
    "save_replay_buffer",
    "save_vec_normalize",
]
