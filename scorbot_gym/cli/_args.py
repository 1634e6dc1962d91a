"""Argument conventions shared by the sub-commands.

One list syntax everywhere: ``--objects banana box`` and ``--objects banana,box`` mean the same,
and names are checked against the valid ones while parsing, before any work starts.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence


class NameList(argparse.Action):
    """``nargs="+"`` whose items may also be comma-separated; validated against ``choices``."""

    def __init__(self, option_strings, dest, valid: Sequence[str] | None = None, **kwargs):
        self.valid = tuple(valid) if valid is not None else None
        kwargs.setdefault("nargs", "+")
        super().__init__(option_strings, dest, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None):
        names = [n.strip() for v in values for n in str(v).split(",") if n.strip()]
        if not names:
            parser.error(f"{option_string} needs at least one name")
        if self.valid is not None:
            bad = [n for n in names if n not in self.valid]
            if bad:
                parser.error(
                    f"{option_string}: unknown {', '.join(map(repr, bad))}; "
                    f"valid: {', '.join(self.valid)}"
                )
        setattr(namespace, self.dest, names)


def add_name_list(
    parser: argparse.ArgumentParser, flag: str, valid: Sequence[str] | None, help: str, **kwargs
) -> None:
    """Add a list option in the shared syntax (``valid`` listed in ``--help``)."""
    if valid is not None:
        help = f"{help} (space- or comma-separated; valid: {', '.join(valid)})"
    parser.add_argument(flag, action=NameList, valid=valid, help=help, **kwargs)


def positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be an integer >= 1, got {text}")
    return value


def non_negative_int(text: str) -> int:
    value = int(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be an integer >= 0, got {text}")
    return value


def non_negative_float(text: str) -> float:
    value = float(text)
    if not value >= 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, got {text}")
    return value


def probability(text: str) -> float:
    value = float(text)
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"must be a probability in [0, 1], got {text}")
    return value


def seed_list(text: str) -> list[int]:
    """``0,1,2``: distinct seeds >= 0 (``--seeds``)."""
    try:
        seeds = [int(s) for s in text.split(",") if s.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be comma-separated integers, got {text}") from None
    if not seeds or len(set(seeds)) != len(seeds) or min(seeds) < 0:
        raise argparse.ArgumentTypeError(f"must be distinct integers >= 0, got {text}")
    return seeds


def add_ray(parser: argparse.ArgumentParser, help: str) -> None:
    """``--ray [ADDRESS]``: ``"local"`` without an address, else the cluster's address."""
    parser.add_argument(
        "--ray", nargs="?", const="local", default=None, metavar="ADDRESS", help=help
    )


def add_episode_workers(parser: argparse.ArgumentParser) -> None:
    """``--jobs N`` and ``--ray [ADDRESS]``: where the episodes run. Every episode depends on
    its seed alone, so the results are the same for any choice."""
    parser.add_argument(
        "--jobs",
        type=positive_int,
        default=1,
        help="processes, each running a chunk of an arm's episodes (results do not depend on "
        "it; with --ray local, the local Ray instance's CPUs)",
    )
    add_ray(
        parser,
        "run the chunks as Ray tasks: a local instance, or join ADDRESS (auto, "
        "ray://host:port; its workers need scorbot-gym installed)",
    )
