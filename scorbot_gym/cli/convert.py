"""``scorbot-gym convert``: rewrite a policy or run folder of SB3's pickle-based format in the
formats that cannot run code (see :mod:`scorbot_gym.rl.convert`)."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "convert",
        help="convert an old policy or run folder (model.zip, *.pkl) to the safe formats",
        description="Write model.safetensors (policy and checkpoint), replay_buffer.npz and "
        "vecnormalize.json next to the pickle-based files of an older policy folder, training "
        "run folder or --seeds folder, which the loaders refuse. Reading the old files runs "
        "any code they hold: give --trust-pickle only for folders you trust. The old files "
        "are left in place.",
    )
    p.add_argument("path", type=Path, help="a policy folder, a run folder or a --seeds folder")
    p.add_argument(
        "--trust-pickle",
        action="store_true",
        help="read the pickle-based files (they can run code: only for folders you trust)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from scorbot_gym.rl.convert import convert

    written = convert(args.path, trust_pickle=args.trust_pickle)
    if not written:
        print(f"nothing to convert: {args.path} has no files in the old pickle-based format")
        return 0
    for path in written:
        print(f"wrote {path}")
    print("the old files are left in place and no longer read; delete them once you have checked")
    return 0
