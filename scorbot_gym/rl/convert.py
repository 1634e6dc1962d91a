"""Convert policy and run folders written in SB3's pickle-based format (``scorbot-gym convert``).

Before the safe formats (:mod:`scorbot_gym.policies.sb3_files`, :mod:`scorbot_gym.rl.checkpoint`)
a policy folder held ``model.zip`` and a run's ``checkpoint/`` held ``model.zip``,
``replay_buffer.pkl`` and ``vecnormalize.pkl``. Reading those unpickles them, which runs any code
a crafted file holds, so the loaders refuse them and this is the one place that reads them: only
when the user says they trust the folder (``trust_pickle=True``, ``--trust-pickle``). The new
files are written next to the old ones, which are left in place (no longer read).
"""

from __future__ import annotations

import pickle
from pathlib import Path

from scorbot_gym.policies.sb3 import _algorithms, read_policy_json
from scorbot_gym.policies.sb3_files import MODEL_FILE, OLD_MODEL_FILE, load_model, save_model
from scorbot_gym.rl import checkpoint, runs
from scorbot_gym.rl.callbacks import atomic_save


def _policy_folders(folder: Path) -> list[Path]:
    return [folder / n for n in (runs.POLICY, runs.BEST) if (folder / n / "policy.json").is_file()]


def _folders(path: Path) -> tuple[list[Path], list[Path]]:
    """The policy folders and the run folders (with a checkpoint) that ``path`` holds."""
    if (path / "policy.json").is_file():
        return [path], []
    if (path / runs.CONFIG).is_file():
        return _policy_folders(path), [path]
    seeds = runs.seed_runs(path)
    if seeds or (path / runs.SEEDS).is_file():
        return [p for s in seeds for p in _policy_folders(s)], [
            s for s in seeds if (s / runs.CONFIG).is_file()
        ]
    raise FileNotFoundError(f"no policy folder or training run folder at {path}")


def old_format_files(path: str | Path) -> list[Path]:
    """The files under ``path`` in the pickle-based format that have no converted counterpart."""
    policies, run_folders = _folders(Path(path))
    found = [p / OLD_MODEL_FILE for p in policies if not (p / MODEL_FILE).is_file()]
    for run in run_folders:
        ck = run / runs.CHECKPOINT
        found += [ck / old for new, old in checkpoint.OLD_FILES.items() if not (ck / new).is_file()]
    return [f for f in found if f.is_file()]


def _convert_policy(folder: Path) -> Path:
    meta = read_policy_json(folder / "policy.json")
    algos = _algorithms()
    if meta.get("algo") not in algos:
        raise ValueError(f"{folder / 'policy.json'}: algo must be one of {sorted(algos)}")
    model = algos[meta["algo"]].load(folder / OLD_MODEL_FILE, device="cpu")
    target = folder / MODEL_FILE
    atomic_save(target, lambda p: save_model(model, p))
    again = load_model(target).policy.state_dict()  # the same weights, read back the safe way
    before = model.policy.state_dict()
    if set(again) != set(before) or any(not again[k].equal(before[k]) for k in before):
        target.unlink()
        raise ValueError(f"{folder}: the converted weights differ from model.zip; nothing written")
    return target


def _convert_checkpoint(run: Path) -> list[Path]:
    from stable_baselines3.common.save_util import load_from_pkl

    from scorbot_gym.rl.training import TrainConfig, _model_class

    ck, written = run / runs.CHECKPOINT, []
    config = TrainConfig.from_json(runs.read_json(run / runs.CONFIG, "a training configuration"))
    if (ck / OLD_MODEL_FILE).is_file() and not (ck / checkpoint.MODEL).is_file():
        model = _model_class(config).load(ck / OLD_MODEL_FILE, device="cpu")
        atomic_save(ck / checkpoint.MODEL, lambda p: save_model(model, p, training=True))
        written.append(ck / checkpoint.MODEL)
    old = ck / checkpoint.OLD_FILES[checkpoint.REPLAY_BUFFER]
    if old.is_file() and not (ck / checkpoint.REPLAY_BUFFER).is_file():
        buffer = load_from_pkl(old)
        atomic_save(
            ck / checkpoint.REPLAY_BUFFER, lambda p: checkpoint.save_replay_buffer(buffer, p)
        )
        written.append(ck / checkpoint.REPLAY_BUFFER)
    old = ck / checkpoint.OLD_FILES[checkpoint.VEC_NORMALIZE]
    if old.is_file() and not (ck / checkpoint.VEC_NORMALIZE).is_file():
        with open(old, "rb") as f:
            stats = pickle.load(f)  # trusted by the caller (trust_pickle)
        checkpoint.save_vec_normalize(stats, ck / checkpoint.VEC_NORMALIZE)
        written.append(ck / checkpoint.VEC_NORMALIZE)
    return written


def convert(path: str | Path, trust_pickle: bool = False) -> list[Path]:
    """Write the safe files for every pickle-based one under ``path`` (a policy folder, a run
    folder or a ``--seeds`` folder); returns the files written ([] if there was nothing to
    convert). Without ``trust_pickle`` a folder that needs converting is refused unread."""
    path = Path(path)
    old = old_format_files(path)
    if not old:
        return []
    if not trust_pickle:
        names = ", ".join(str(f.relative_to(path)) for f in old)
        raise ValueError(
            f"{path} holds files in the old pickle-based format ({names}), which run code when "
            f"loaded; if you trust where they came from: scorbot-gym convert {path} --trust-pickle"
        )
    policies, run_folders = _folders(path)
    written = []
    for folder in policies:
        if (folder / OLD_MODEL_FILE).is_file() and not (folder / MODEL_FILE).is_file():
            written.append(_one_line(_convert_policy, folder))
    for run in run_folders:
        written += _one_line(_convert_checkpoint, run)
    return written


def _one_line(convert_one, folder: Path):
    """``convert_one(folder)`` with a damaged old file (SB3, zip and pickle raise many kinds)
    as a one-line error naming the folder."""
    try:
        return convert_one(folder)
    except Exception as exc:
        msg = str(exc).splitlines()[0] if str(exc) else ""
        raise ValueError(f"cannot convert {folder}: {type(exc).__name__}: {msg[:300]}") from None


__all__ = ["convert", "old_format_files"]
