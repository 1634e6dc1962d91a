"""The ``scorbot-gym`` command line.

Each sub-command lives in its own module exposing ``add_parser(subparsers)``; the parser it adds
sets ``func`` (called with the parsed arguments, returns the exit code).
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

# Modules that contribute sub-commands, in the order ``--help`` lists them.
_COMMAND_MODULES = (
    "scorbot_gym.cli.rollout",
    "scorbot_gym.cli.doctor",
    "scorbot_gym.cli.pose_cmd",
    "scorbot_gym.cli.shapes_cmd",
    "scorbot_gym.cli.train",
    "scorbot_gym.cli.compare",
    "scorbot_gym.cli.demos",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="scorbot-gym",
        description="Simulated SCORBOT-ER Vplus grasping with pose-manifold vision.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in _COMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:  # a sub-command module not written yet
            if exc.name == name:
                continue
            raise
        module.add_parser(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (ValueError, FileNotFoundError, KeyError) as exc:
        print(f"scorbot-gym {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
