"""Atomic file writes: a crash or a full disk never leaves a half-written file behind.

Every file the project saves (models, cached datasets, benchmark results, figures) goes through
:func:`atomic_write`: the content is written to a temporary file in the target folder, flushed,
given the permissions a plain ``open`` would give, and renamed over the target in one step.

Caches built on these files heal themselves: an entry that cannot be read (truncated,
bit-flipped, from an older layout) is discarded with a warning and rebuilt
(:func:`discard_cache_entry`, :data:`UNREADABLE`), and the temporary files of writes that were
killed midway are removed on a later run (:func:`remove_orphaned_tmp`): a temporary file's name
carries its writer's host and process id, so one whose writer is dead goes at once, and one whose
writer cannot be judged (another host, an older name) once it is old enough.
"""

from __future__ import annotations

import gzip
import json
import os
import re
import socket
import tempfile
import time
import warnings
import zipfile
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

import numpy as np


def atomic_write(path: str | os.PathLike, write: Callable[[IO[bytes]], None]) -> Path:
    """Call ``write(f)`` on a temporary file, then rename it to ``path``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.{_writer()}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp creates 0600 files
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    return atomic_write(path, lambda f: f.write(data))


def atomic_write_json(path: str | os.PathLike, obj: Any) -> Path:
    """Indented JSON; gzip-compressed when the name ends in ``.gz`` (records that keep per-view
    arrays shrink about tenfold, and :func:`read_json` reads both)."""
    data = (json.dumps(obj, indent=2) + "\n").encode()
    if Path(path).suffix == ".gz":
        data = gzip.compress(data, compresslevel=9, mtime=0)  # mtime 0: same content, same bytes
    return atomic_write_bytes(path, data)


def read_json(path: str | os.PathLike) -> Any:
    """A JSON file as :func:`atomic_write_json` writes it, gzip-compressed or not."""
    raw = Path(path).read_bytes()
    return json.loads(gzip.decompress(raw) if raw[:2] == b"\x1f\x8b" else raw)


def atomic_savez(path: str | os.PathLike, **arrays: np.ndarray) -> Path:
    """``np.savez_compressed`` to ``path``, atomically (the name is kept as given)."""
    return atomic_write(path, lambda f: np.savez_compressed(f, **arrays))


# What reading a damaged .npz can raise: numpy's and zipfile's format errors, zlib's for a
# corrupt deflate stream, EOFError for a truncated member, KeyError/TypeError for missing or
# mistyped entries, ValueError (incl. JSON) for bad contents, OSError for the file itself.
UNREADABLE = (OSError, ValueError, KeyError, TypeError, EOFError, zipfile.BadZipFile, zlib.error)
ORPHAN_AGE_S = 600.0


def discard_cache_entry(path: str | os.PathLike, error: BaseException) -> None:
    """Delete an unreadable cache entry, saying so, so that the caller rebuilds it."""
    warnings.warn(
        f"discarding unreadable cache entry {path} ({type(error).__name__}: {error}); "
        "it will be rebuilt",
        RuntimeWarning,
        stacklevel=3,
    )
    Path(path).unlink(missing_ok=True)


def cached_npz(path: str | os.PathLike, load, build):
    """``load(path)`` of a content-keyed ``.npz`` cache entry: built first (``build()`` returns
    the arrays, written atomically) if it is missing, discarded and rebuilt if it is unreadable.
    Temporary files of dead writers in its folder are removed on the way."""
    path = Path(path)
    if path.parent.is_dir():
        remove_orphaned_tmp(path.parent)
    if path.is_file():
        try:
            return load(path)
        except UNREADABLE as exc:
            discard_cache_entry(path, exc)
    atomic_savez(path, **build())
    return load(path)


def _writer() -> str:
    """``host-pid`` of this process, as temporary file names carry it (dots would split it)."""
    return f"{socket.gethostname().replace('.', '_')}-{os.getpid()}"


# .NAME.HOST-PID.RANDOM.tmp (atomic_write) and .STEM.tmpPID.SUFFIX (an SB3 checkpoint's, whose
# writer appends the suffix itself); older names without a writer match neither.
_TMP_WRITER = (
    re.compile(r"^\..+\.(?P<host>[^.]+)-(?P<pid>\d+)\.[^.]+\.tmp$"),
    re.compile(r"^\..+\.tmp(?P<pid>\d+)(\.[^.]+)?$"),
)


def _writer_is_dead(name: str) -> bool:
    """Whether ``name``'s writer was a process of this host that no longer runs."""
    for pattern in _TMP_WRITER:
        m = pattern.match(name)
        if m is None:
            continue
        host = m.groupdict().get("host")
        if host is not None and host != _writer().rsplit("-", 1)[0]:
            return False  # another machine's write (a shared cache): only age can tell
        pid = int(m["pid"])
        if pid == os.getpid():
            return False
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return True
        except PermissionError:  # alive, another user's
            return False
        return False
    return False


def remove_orphaned_tmp(folder: str | os.PathLike, min_age_s: float = ORPHAN_AGE_S) -> int:
    """Remove the temporary files that killed writes left in ``folder``; returns how many.

    A file whose writer (named in it, see :func:`_writer`) is a dead process of this host goes
    at once; any other only once untouched for ``min_age_s``: it may be another process's write
    in progress (the cache is shared, also across machines)."""
    now, removed = time.time(), 0
    for tmp in Path(folder).glob(".*.tmp*"):
        if not any(p.match(tmp.name) for p in _TMP_WRITER) and not tmp.name.endswith(".tmp"):
            continue
        try:
            if _writer_is_dead(tmp.name) or now - tmp.stat().st_mtime >= min_age_s:
                tmp.unlink()
                removed += 1
        except FileNotFoundError:  # its writer finished or another cleaner got there first
            continue
    return removed


# ---- benchmark result files: one per script, variants as named configs ----------------------

#: the key under which a result file keeps its named variants (``{"configs": {name: report}}``)
CONFIGS = "configs"


def read_result(path: str | os.PathLike, config: str | None = None) -> dict:
    """One run of a benchmark's result file: the default run (the file's top level, without its
    ``configs``) or, given ``config``, the variant stored under that name.

    A benchmark script keeps everything it measured in one file: the default run at the top level
    and each variant (another seed, another model set, another object list) under
    ``configs[name]``, so that one file answers "what did this script measure"."""
    data = read_json(path)
    if config is None:
        return {k: v for k, v in data.items() if k != CONFIGS}
    configs = data.get(CONFIGS, {})
    if config not in configs:
        known = ", ".join(configs) or "none"
        raise KeyError(f"{path} has no config {config!r}; its configs: {known}")
    return configs[config]


def result_configs(path: str | os.PathLike) -> list[str]:
    """The names of the variants a result file holds (its default run not counted)."""
    return list(read_json(path).get(CONFIGS, {})) if Path(path).is_file() else []


def write_result(path: str | os.PathLike, report: dict, config: str | None = None) -> Path:
    """Store ``report`` as the default run of the result file ``path`` (``config`` None) or as
    its variant ``config``, keeping every other run the file holds: rerunning one variant never
    drops the others."""
    if CONFIGS in report:
        raise ValueError(f"a report may not carry its own {CONFIGS!r} key")
    data = read_json(path) if Path(path).is_file() else {}
    configs = dict(data.get(CONFIGS, {}))
    if config is None:
        data = dict(report)
    else:
        configs[config] = report
    if configs:
        data[CONFIGS] = configs
    return atomic_write_json(path, data)
