"""The ``scorbot-gym`` command line.

Each sub-command lives in its own module exposing ``add_parser(subparsers)``; the parser it adds
sets ``func`` (called with the parsed arguments, returns the exit code).

A module is imported only when its sub-command is parsed or its help printed: the options' valid
names come from the simulator, the object catalogue and the learners (MuJoCo, OpenCV, torch:
seconds of imports), which ``scorbot-gym --help``, an unknown command and the other sub-commands
need not pay. :data:`COMMANDS` therefore lists each sub-command with its one-line help.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Callable, Sequence

# name -> (module that adds its parser, one-line help), in the order ``--help`` lists them.
COMMANDS: dict[str, tuple[str, str]] = {
    "rollout": ("scorbot_gym.cli.rollout", "run seeded grasping episodes and summarize them"),
    "doctor": (
        "scorbot_gym.cli.doctor",
        "check headless rendering, frames per second and the default models",
    ),
    "pose": ("scorbot_gym.cli.pose_cmd", "train and evaluate the pose-manifold estimator"),
    "shapes": (
        "scorbot_gym.cli.shapes_cmd",
        "silhouette shape recognition (Fourier + ART + affine moments; FLR)",
    ),
    "train": (
        "scorbot_gym.cli.train",
        "train a learned grasping policy (SB3 SAC/TQC/PPO), or resume a run",
    ),
    "compare": (
        "scorbot_gym.cli.compare",
        "compare policies (scripted, rl, random, a policy directory) on paired seeds",
    ),
    "demos": ("scorbot_gym.cli.demos", "record scripted demonstrations as a Minari dataset"),
    "convert": (
        "scorbot_gym.cli.convert",
        "convert an old policy or run folder (model.zip, *.pkl) to the safe formats",
    ),
}


class CommandParser(argparse.ArgumentParser):
    """A sub-command's parser whose options ``fill(parser)`` adds on first use.

    ``fill`` runs once, before the parser parses its arguments or formats its help. The parser
    records its ``prog`` (``scorbot-gym pose ablate``) as ``command_prog`` in the namespace, so
    that errors found after parsing name the sub-command as argparse's own errors do.
    """

    def __init__(self, *args, fill: Callable[[argparse.ArgumentParser], None] | None = None, **kw):
        super().__init__(*args, **kw)
        self._fill = fill
        self.set_defaults(command_prog=self.prog)

    def _filled(self) -> None:
        fill, self._fill = self._fill, None
        if fill is not None:
            fill(self)

    def parse_known_args(self, args=None, namespace=None):
        self._filled()
        return super().parse_known_args(args, namespace)

    def format_help(self) -> str:
        self._filled()
        return super().format_help()

    def format_usage(self) -> str:
        self._filled()
        return super().format_usage()


class _ListedCommand:
    """What a command module's ``add_parser(subparsers)`` receives: its ``subparsers.add_parser``
    hands back the command's parser, already listed in ``--help``, taking the description."""

    def __init__(self, parser: CommandParser):
        self.parser = parser

    def add_parser(self, name: str, *, description: str | None = None, **_listed) -> CommandParser:
        if name != self.parser.prog.rsplit(" ", 1)[-1]:
            raise ValueError(f"{self.parser.prog!r} is listed, but its module adds {name!r}")
        if description is not None:
            self.parser.description = description
        return self.parser


def _filler(module: str) -> Callable[[argparse.ArgumentParser], None]:
    def fill(parser: argparse.ArgumentParser) -> None:
        importlib.import_module(module).add_parser(_ListedCommand(parser))

    return fill


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="scorbot-gym",
        description="Simulated SCORBOT-ER Vplus grasping with pose-manifold vision.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=CommandParser)
    sub.required = True
    for name, (module, help) in COMMANDS.items():
        sub.add_parser(name, help=help, fill=_filler(module))
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (ValueError, OSError, KeyError) as exc:  # OSError: e.g. a disk that filled up
        print(f"{args.command_prog}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
