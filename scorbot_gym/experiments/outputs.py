"""Where a benchmark writes: a fresh run folder by default, never over a file it was not told to.

The committed results (``benchmarks/results/``) and the shipped policies
(``scorbot_gym/policies/data/``) are records: a benchmark run with its defaults must not
replace them. So a script's outputs go to a new folder ``runs/<script>-<UTC time>/`` unless
``--out`` (or the script's own path option) names a path, and a named path that exists already
is refused, with a one-line usage error before any work starts, unless ``--overwrite`` is given
too. Regenerating a committed result is then explicit::

    python benchmarks/compare.py --out benchmarks/results/compare.json --overwrite
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Sequence
from pathlib import Path

#: where default outputs go (relative to the working directory, like ``scorbot-gym train``'s)
RUNS_ROOT = Path("runs")


def add_overwrite_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="replace the files that the output options name if they exist (without it an "
        "existing file is refused; by default outputs go to a new runs/<script>-<time>/)",
    )


def fresh_run_folder(script: str, root: Path = RUNS_ROOT) -> Path:
    """A folder ``root/<script>-<UTC time>`` that does not exist yet (not created here)."""
    stamp = time.strftime("%Y%m%d-%H%M%S", time.gmtime())
    folder = Path(root) / f"{script}-{stamp}"
    k = 1
    while folder.exists():
        folder = Path(root) / f"{script}-{stamp}-{k}"
        k += 1
    return folder


def refuse_existing(paths: Sequence[Path], option: str) -> None:
    """One-line error if any of ``paths`` (what ``option`` would write) exists."""
    for path in paths:
        if Path(path).exists():
            raise ValueError(
                f"{option} {path} exists; add --overwrite to replace it, or name a new path "
                "(without the option, outputs go to a new runs/<script>-<time>/ folder)"
            )


class Outputs:
    """The output paths of one benchmark run.

    ``path(given, name, option)`` is ``given`` when the user named one (refused if it exists,
    or if any of its ``companions``, e.g. the ``.png`` beside a JSON, does, unless
    ``overwrite``), else ``<run folder>/<name>``, the run folder being fresh."""

    def __init__(self, script: str, overwrite: bool = False, root: Path = RUNS_ROOT) -> None:
        self.script, self.overwrite, self.root = script, overwrite, Path(root)
        self._folder: Path | None = None

    @property
    def folder(self) -> Path:
        if self._folder is None:
            self._folder = fresh_run_folder(self.script, self.root)
        return self._folder

    def path(
        self,
        given: str | Path | None,
        name: str,
        option: str = "--out",
        companions: Sequence[str] = (),
    ) -> Path:
        if given is None:
            return self.folder / name
        path = Path(given)
        if not self.overwrite:
            refuse_existing([path, *(companion(path, s) for s in companions)], option)
        return path


def companion(path: Path, suffix: str) -> Path:
    """The file written beside ``path`` with ``suffix`` (``x.json``, ``x.json.gz`` -> ``x.png``)."""
    name = Path(path).name
    for ext in (".json.gz", ".json"):
        if name.endswith(ext):
            return Path(path).with_name(name[: -len(ext)] + suffix)
    return Path(path).with_suffix(suffix)


__all__ = [
    "RUNS_ROOT",
    "Outputs",
    "add_overwrite_option",
    "companion",
    "fresh_run_folder",
    "refuse_existing",
]
