"""Where a trained policy came from, recorded in its ``policy.json`` so that it can be rebuilt.

Every trainer (imitation, RL from scratch, residual RL, RL fine-tuning, pixel imitation) adds
two keys to the policy it writes:

- ``"trained_by"``: one of :data:`TRAINED_BY`;
- ``"provenance"``: the command as it was run (``sys.argv``), the code (``git rev-parse HEAD``
  and whether tracked files had uncommitted changes when the package runs from a checkout, and
  the package version), the data (episodes and their seed ranges, or the dataset's id and file
  hash), the pose models the learner observed (a content hash of the model set; ``null`` for
  the oracle pose), the library versions and the time.

What is not known is said to be unknown (``"unknown"``; :data:`NOT_RECORDED` for the policies
trained before this record existed), never guessed. This module imports no SB3 or torch.
"""

from __future__ import annotations

import hashlib
import platform
import subprocess
import sys
import time
from importlib import metadata
from pathlib import Path
from typing import Any

TRAINED_BY = ("imitation", "rl_finetune", "rl_from_scratch", "residual", "pixel_imitation")
UNKNOWN = "unknown"
#: what a policy trained before this record existed says for a fact nobody wrote down
NOT_RECORDED = "not recorded"
#: the libraries whose versions change what a training run produces
LIBRARIES = ("numpy", "torch", "stable-baselines3", "sb3-contrib", "gymnasium", "mujoco")

_PACKAGE_ROOT = Path(__file__).resolve().parents[2]  # the folder holding scorbot_gym/ and pose/
_digests: dict[int, tuple[Any, dict[str, Any]]] = {}


def _git(*args: str) -> str | None:
    try:
        done = subprocess.run(
            ["git", "-C", str(_PACKAGE_ROOT), *args],
            capture_output=True,
            text=True,
            timeout=10,
            check=False,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return done.stdout.strip() if done.returncode == 0 else None


def code_version() -> dict[str, Any]:
    """``{"commit", "uncommitted_changes", "version"}`` of the code that runs.

    ``commit`` is ``git rev-parse HEAD`` when the package is imported from a git checkout
    (the checkout's top folder holds ``scorbot_gym/``), else ``"unknown"``;
    ``uncommitted_changes`` whether tracked files differ from it (``None`` when unknown);
    ``version`` the installed distribution's version, or ``"unknown"``."""
    top = _git("rev-parse", "--show-toplevel")
    commit, dirty = UNKNOWN, None
    if top is not None and Path(top).resolve() == _PACKAGE_ROOT:
        commit = _git("rev-parse", "HEAD") or UNKNOWN
        status = _git("status", "--porcelain", "--untracked-files=no")
        dirty = None if status is None else bool(status)
    try:
        version = metadata.version("scorbot-gym")
    except metadata.PackageNotFoundError:
        version = UNKNOWN
    return {"commit": commit, "uncommitted_changes": dirty, "version": version}


def library_versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for name in LIBRARIES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def file_sha256(path: str | Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def folder_sha256(path: str | Path) -> str:
    """One hash over the names and contents of a folder's files (sorted; recursive)."""
    root = Path(path)
    h = hashlib.sha256()
    for f in sorted(p for p in root.rglob("*") if p.is_file()):
        h.update(str(f.relative_to(root)).encode() + b"\0" + file_sha256(f).encode())
    return h.hexdigest()


def pose_model_identity(models: Any) -> dict[str, Any] | None:
    """The identity of the pose models a learner observed: ``None`` (no models: the oracle or
    a noisy oracle), a model file's path and SHA-256, or for a loaded
    :class:`pose.model_set.PoseModelSet` the SHA-256 of its arrays and header (the same models
    give the same hash whichever file they came from), with the cache key of the default
    models (:func:`scorbot_gym.perception.training.default_pose_models`) when they are those."""
    if models is None:
        return None
    if isinstance(models, (str, Path)):
        path = Path(models)
        return {"file": str(path), "sha256": file_sha256(path)}
    cached = _digests.get(id(models))
    if cached is not None and cached[0] is models:
        return cached[1]
    h = hashlib.sha256()
    names = list(getattr(models, "object_names", []))
    h.update(repr(names).encode())
    for i, name in enumerate(names):
        est = models.estimators[name]
        h.update(type(est).__name__.encode())
        arrays = est.to_arrays(prefix=f"o{i}/")
        for key in sorted(arrays):
            a = arrays[key]
            h.update(f"{key}{getattr(a, 'dtype', '')}{getattr(a, 'shape', '')}".encode())
            h.update(a.tobytes() if hasattr(a, "tobytes") else repr(a).encode())
    meta = getattr(models, "meta", {}) or {}
    identity = {
        "sha256": h.hexdigest(),
        "objects": names,
        "cache_key": meta.get("cache_key"),
    }
    _digests[id(models)] = (models, identity)
    return identity


def env_pose_models(env: Any) -> dict[str, Any] | None:
    """:func:`pose_model_identity` of the models behind an env's pose wrapper (``None`` for a
    source without models)."""
    try:
        source = env.get_wrapper_attr("source")
    except AttributeError:
        return None
    return pose_model_identity(getattr(source, "models", None))


def seed_span(seeds: range) -> dict[str, Any] | None:
    """A compact record of consecutive seeds, with the named range they lie in."""
    from scorbot_gym.seeds import range_of

    if len(seeds) == 0:
        return None
    first, last = seeds[0], seeds[-1]
    named = range_of(first)
    return {
        "first": first,
        "last": last,
        "count": len(seeds),
        "range": named.name if named is not None and last in named else None,
    }


def policy_identity(path: str | Path, meta: dict[str, Any]) -> dict[str, Any]:
    """What a policy that another was trained from is: its folder, the hash of its files, and
    what its own ``policy.json`` says about how it was made."""
    return {
        "path": str(path),
        "sha256": folder_sha256(path),
        "trained_by": meta.get("trained_by", NOT_RECORDED),
        "provenance": meta.get("provenance", NOT_RECORDED),
    }


def record(
    trained_by: str,
    data: dict[str, Any],
    pose_models: dict[str, Any] | list | None,
    command: list[str] | None = None,
) -> dict[str, Any]:
    """The ``trained_by`` and ``provenance`` keys of a new policy's ``policy.json``."""
    if trained_by not in TRAINED_BY:
        raise ValueError(f"trained_by must be one of {TRAINED_BY}, got {trained_by!r}")
    return {
        "trained_by": trained_by,
        "provenance": {
            "command": list(sys.argv if command is None else command),
            "code": code_version(),
            "data": data,
            "pose_models": pose_models,
            "libraries": library_versions(),
            "recorded_at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        },
    }


__all__ = [
    "NOT_RECORDED",
    "TRAINED_BY",
    "UNKNOWN",
    "code_version",
    "env_pose_models",
    "file_sha256",
    "folder_sha256",
    "library_versions",
    "policy_identity",
    "pose_model_identity",
    "record",
    "seed_span",
]
