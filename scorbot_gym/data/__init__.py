"""Rendered, labelled data for the vision side: pose views and silhouettes, cached on disk."""

from __future__ import annotations

import atexit
import os
import shutil
import tempfile
import warnings
from pathlib import Path

CACHE_ENV = "SCORBOT_GYM_CACHE"
_usable: dict[Path, Path] = {}  # configured folder -> the folder used (itself or a fallback)


def default_cache_dir() -> Path:
    """Where rendered views, silhouettes, fitted models and derived object geometry are cached:
    ``$SCORBOT_GYM_CACHE``, else ``~/.cache/scorbot-gym``. Defined here, not in ``views``, so
    that finding it imports nothing else (an env looks it up at ``make``).

    A folder that cannot be written (read-only, a path through a regular file, no home) is not
    fatal: the cache only saves time. This process then caches in a temporary folder, removed
    at exit, and says so once in a one-line warning; its worker processes inherit the fallback
    through ``$SCORBOT_GYM_CACHE``.
    """
    env = os.environ.get(CACHE_ENV)
    wanted = Path(env) if env else Path.home() / ".cache" / "scorbot-gym"
    if wanted not in _usable:
        _usable[wanted] = _writable_or_temporary(wanted)
    return _usable[wanted]


def cache_folder(cache_dir: str | os.PathLike | None = None) -> Path:
    """The cache folder to use: ``cache_dir`` if given (a one-line ``ValueError`` if it cannot
    be written: the caller asked for that folder), else :func:`default_cache_dir`."""
    if cache_dir is None or cache_dir == "":
        return default_cache_dir()
    folder = Path(cache_dir)
    try:
        _probe(folder)
    except OSError as err:
        raise ValueError(
            f"cache folder {folder} is not writable ({err.strerror or type(err).__name__}); "
            f"give a writable folder, or none to use ${CACHE_ENV} or ~/.cache/scorbot-gym"
        ) from err
    return folder


def _probe(folder: Path) -> None:
    """Create ``folder`` and a file in it (tried, not ``os.access``: root may write anywhere
    but on a read-only mount)."""
    folder.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryFile(dir=folder):
        pass


def _writable_or_temporary(folder: Path) -> Path:
    """``folder`` if a file can be created in it, else a new temporary folder."""
    try:
        _probe(folder)
        return folder
    except OSError as err:
        fallback = Path(tempfile.mkdtemp(prefix="scorbot-gym-cache-"))
        atexit.register(shutil.rmtree, fallback, ignore_errors=True)
        os.environ[CACHE_ENV] = str(fallback)
        _usable[fallback] = fallback
        reason = err.strerror or type(err).__name__
        warnings.warn(
            f"cache folder {folder} is not writable ({reason}); caching in {fallback} for this "
            f"run only (set {CACHE_ENV} to a writable folder to keep rendered views and models)",
            RuntimeWarning,
            stacklevel=3,
        )
        return fallback
