"""Checking where results will go before the work that makes them starts, and writing them so
that nothing half-made is ever left behind.

A rollout, a comparison, a pose-model fit or a demonstration run can take minutes to hours; an
output that cannot be written must be refused before the first episode, not after the last.
Every command that writes checks its outputs with this module first:

- :func:`check_output_file` -- a file path: not empty, not a folder, a suffix the writer
  understands, and a parent folder that exists (or can be made) and accepts a new file;
- :func:`check_output_folder` -- a folder that exists or can be made, and accepts new files;
- :func:`check_dataset_id` -- a Minari dataset id (``namespace/name-vN``) that is well formed
  and not taken.

Writability is tested by creating (and at once removing) a temporary file in the nearest
existing folder: permission bits say nothing for root, read-only mounts or ``/sys``.

The writes themselves are atomic (:func:`atomic_write` and friends, from :mod:`pose.fileio`: a
temporary file in the target's folder, renamed over it in one step), and a folder-shaped result
is built under a hidden staging name and renamed into place (:func:`staging_dir`). A folder
that one process must own for a long time (a training run) is held with
:func:`exclusive_lock` (``fcntl.flock``), so a second process is refused instead of
overwriting it.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import re
import shutil
import socket
import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path

from pose.fileio import atomic_savez, atomic_write, atomic_write_bytes, atomic_write_json


class OutputError(ValueError):
    """An output that cannot be written (one line: the option, the path, what is wrong)."""


def _label(what: str, path: object) -> str:
    return f"{what} {path}" if what else str(path)


def _as_path(text: str | os.PathLike, what: str, kind: str) -> Path:
    raw = os.fspath(text)
    if raw == "":
        raise OutputError(f"{what}: an empty path is not a {kind} name; give one")
    if "\0" in raw:
        raise OutputError(f"{what}: the path contains a NUL character")
    return Path(raw)


def _nearest_existing(path: Path, what: str, target: Path) -> Path:
    """The first of ``path`` and its parents that exists; it must be a folder."""
    path = Path(os.path.abspath(path))
    for candidate in (path, *path.parents):
        if candidate.exists():
            if not candidate.is_dir():
                raise OutputError(
                    f"{_label(what, target)}: {candidate} is a file, so nothing can be "
                    "created under it"
                )
            return candidate
    return Path("/")  # unreachable: the root exists


def _probe_writable(folder: Path, what: str, target: Path) -> None:
    """Create and remove a temporary file in ``folder``: the only test that root, read-only
    mounts and pseudo file systems all answer truthfully."""
    try:
        fd, tmp = tempfile.mkstemp(dir=folder, prefix=".scorbot-gym-probe.")
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__
        raise OutputError(
            f"{_label(what, target)}: cannot write into {folder} ({reason})"
        ) from None
    os.close(fd)
    os.unlink(tmp)


def check_output_folder(path: str | os.PathLike, what: str = "") -> Path:
    """``path`` as a folder that exists or can be made, and takes new files; else a one-line
    :class:`OutputError` naming ``what`` (the option, e.g. ``"--out"``). Creates nothing."""
    out = _as_path(path, what, "folder")
    try:
        if out.exists() and not out.is_dir():
            raise OutputError(f"{_label(what, out)} is a file, not a folder")
        _probe_writable(_nearest_existing(out, what, out), what, out)
    except OSError as exc:  # a name too long, a loop of links...
        raise OutputError(f"{_label(what, out)}: {exc.strerror or exc}") from None
    return out


def check_output_file(
    path: str | os.PathLike, what: str = "", suffixes: Sequence[str] | None = None
) -> Path:
    """``path`` as a file that can be written (and replaced, atomically, if it exists):
    not empty, not a folder, ending in one of ``suffixes`` (case-insensitive; ``None``: any),
    its folder existing or creatable and writable. One-line :class:`OutputError` otherwise.
    Creates nothing."""
    out = _as_path(path, what, "file")
    try:
        if out.is_dir():
            raise OutputError(f"{_label(what, out)} is a folder; give a file name")
        if suffixes and not out.name.lower().endswith(tuple(s.lower() for s in suffixes)):
            raise OutputError(f"{_label(what, out)}: the name must end in {' or '.join(suffixes)}")
        _probe_writable(_nearest_existing(out.parent, what, out), what, out)
    except OSError as exc:
        raise OutputError(f"{_label(what, out)}: {exc.strerror or exc}") from None
    return out


# --- exclusive use of a folder --------------------------------------------------------------


_HELD = (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES)


def _holder(fd: int) -> str:
    return os.pread(fd, 64, 0).decode(errors="replace").strip()


def _in_use(what: str, holder: str) -> OutputError:
    by = f" (pid {holder})" if holder.isdigit() else ""
    return OutputError(
        f"{what} is in use by another process{by}; wait for it to finish or choose another"
    )


def refuse_if_locked(lock_file: str | os.PathLike, what: str) -> None:
    """The one-line :class:`OutputError` of :func:`exclusive_lock` if another process holds
    ``lock_file`` now; writes nothing (a missing lock file is free)."""
    try:
        fd = os.open(Path(lock_file), os.O_RDONLY)
    except FileNotFoundError:
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)  # conflicts with a holder's LOCK_EX
    except OSError as exc:
        if exc.errno not in _HELD:
            raise
        raise _in_use(what, _holder(fd)) from None
    finally:
        os.close(fd)  # releases the shared lock, if taken


@contextlib.contextmanager
def exclusive_lock(lock_file: str | os.PathLike, what: str) -> Iterator[None]:
    """Hold an exclusive ``flock`` on ``lock_file`` (created if missing) for the ``with`` body.

    A second process asking for it is refused at once with a one-line :class:`OutputError`
    naming ``what`` and the holder's process id. The kernel drops the lock when its holder
    exits, however it exits (a SIGKILL too), so a stale lock file never blocks anyone; the file
    itself is left in place (removing it would let two processes lock two different files)."""
    fd = os.open(Path(lock_file), os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as exc:
        holder = _holder(fd)
        os.close(fd)
        if exc.errno not in _HELD:
            raise
        raise _in_use(what, holder) from None
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        yield
    finally:
        os.close(fd)  # releases the lock


# --- folders built under a staging name -------------------------------------------------------

_STAGING = re.compile(r"^\.scorbot-gym-staging\.(?P<host>[^.]+)-(?P<pid>\d+)\.")


def _host() -> str:
    return socket.gethostname().replace(".", "_")


def _writer_gone(name: str) -> bool:
    """Whether a staging folder's writer (named in it) is a dead process of this host."""
    m = _STAGING.match(name)
    if m is None or m["host"] != _host() or int(m["pid"]) == os.getpid():
        return False
    try:
        os.kill(int(m["pid"]), 0)
    except ProcessLookupError:
        return True
    except PermissionError:  # alive, another user's
        return False
    return False


def remove_orphaned_staging(folder: str | os.PathLike) -> int:
    """Remove the staging folders of :func:`staging_dir` in ``folder`` whose writer is a dead
    process of this host (a killed run); returns how many. Nothing else is touched."""
    removed = 0
    folder = Path(folder)
    if not folder.is_dir():
        return 0
    for entry in folder.iterdir():
        if entry.is_dir() and not entry.is_symlink() and _writer_gone(entry.name):
            shutil.rmtree(entry, ignore_errors=True)
            removed += 1
    return removed


@contextlib.contextmanager
def staging_dir(parent: str | os.PathLike) -> Iterator[Path]:
    """A new hidden folder in ``parent`` to build a result in, removed when the body fails;
    the body moves what it built into place (``os.replace``/``os.rename``: one step on the same
    file system). Its name carries this host and process id, so :func:`remove_orphaned_staging`
    clears it once a killed writer is gone; the staging folders of dead writers in ``parent``
    are cleared on the way in."""
    parent = Path(parent)
    parent.mkdir(parents=True, exist_ok=True)
    remove_orphaned_staging(parent)
    prefix = f".scorbot-gym-staging.{_host()}-{os.getpid()}."
    path = Path(tempfile.mkdtemp(dir=parent, prefix=prefix))
    try:
        yield path
    finally:
        shutil.rmtree(path, ignore_errors=True)


# --- Minari dataset ids ------------------------------------------------------------------------

# Minari 0.5's rules (minari/dataset/minari_dataset.py and minari/namespace.py), with the
# version made compulsory (minari accepts an id without one here and fails later on it) and
# written without leading zeros, no empty namespace level ('a//b').
_NAMESPACE = r"[-_\w][-_\w/]*[-_\w]+"
_DATASET_ID = re.compile(
    rf"^(?:(?P<namespace>{_NAMESPACE})/)?(?P<name>[-_\w]+?)-v(?P<version>0|[1-9]\d*)$"
)


def parse_dataset_id(dataset_id: str, what: str = "dataset id") -> tuple[str | None, str, int]:
    """``(namespace, name, version)`` of a Minari dataset id ``[namespace/]name-vN``; a one-line
    :class:`OutputError` naming the rule if it is malformed."""
    m = _DATASET_ID.fullmatch(dataset_id) if isinstance(dataset_id, str) else None
    namespace = m["namespace"] if m else None
    if m is None or (namespace is not None and "" in namespace.split("/")):
        raise OutputError(
            f"{what} {dataset_id!r} is not a Minari dataset id [namespace/]name-vN: letters, "
            "digits, '-' and '_', a namespace of 2 or more characters, a version number "
            "(e.g. scorbot/grasp-oracle-v0)"
        )
    return namespace, m["name"], int(m["version"])


def datasets_root() -> Path:
    """Where Minari keeps local datasets (``MINARI_DATASETS_PATH``, default
    ``~/.minari/datasets``), read as Minari reads it, without creating it."""
    root = os.environ.get("MINARI_DATASETS_PATH")
    return Path(root) if root is not None else Path.home() / ".minari" / "datasets"


def check_dataset_id(dataset_id: str, what: str = "dataset id") -> Path:
    """The folder a new Minari dataset ``dataset_id`` will occupy: the id well formed, no
    dataset (or anything else) there yet, the datasets folder writable. One-line
    :class:`OutputError` otherwise. Creates nothing."""
    parse_dataset_id(dataset_id, what)
    root = datasets_root()
    check_output_folder(root, f"{what} {dataset_id!r}: the datasets folder")
    target = root / dataset_id
    if target.exists() or target.is_symlink():
        raise OutputError(
            f"{what} {dataset_id!r}: a Minari dataset of that id exists already ({target}); "
            f"choose another name or version, or remove it with minari.delete_dataset"
            f"({dataset_id!r})"
        )
    check_output_folder(target, f"{what} {dataset_id!r}")
    return target


__all__ = [
    "OutputError",
    "atomic_savez",
    "atomic_write",
    "atomic_write_bytes",
    "atomic_write_json",
    "check_dataset_id",
    "check_output_file",
    "check_output_folder",
    "datasets_root",
    "exclusive_lock",
    "parse_dataset_id",
    "refuse_if_locked",
    "remove_orphaned_staging",
    "staging_dir",
]
