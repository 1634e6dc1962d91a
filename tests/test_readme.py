"""Every README code block runs as written.

Python blocks are executed, each in a fresh interpreter in an empty working directory (so they
cannot lean on each other or on files lying around). Shell blocks are checked command by
command: ``scorbot-gym`` commands must parse with the real argument parser (running them all
would take the benchmarks' time) and ``python <script>`` must name a script that exists; other
commands (``pip``, ``pytest``) are left to CI, which runs the install and test commands itself.
``text`` blocks are synopses, not commands.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
README = (ROOT / "README.md").read_text()
BLOCKS = re.findall(r"^```(\w*)\n(.*?)^```", README, flags=re.S | re.M)
PYTHON = [code for lang, code in BLOCKS if lang == "python"]
SHELL = [code for lang, code in BLOCKS if lang in ("bash", "sh", "shell", "console")]


def _commands(block: str) -> list[list[str]]:
    """Shell commands of a block: comments dropped, continuations joined, ``&&`` split."""
    text = re.sub(r"\\\n", " ", block)
    commands = []
    for line in text.splitlines():
        line = line.split(" #", 1)[0].strip()
        if not line or line.startswith("#"):
            continue
        for part in line.split("&&"):
            commands.append(shlex.split(part))
    return commands


def test_readme_has_code_blocks():
    assert len(PYTHON) >= 3 and len(SHELL) >= 2
    assert all(lang in ("python", "bash", "text", "json") for lang, _ in BLOCKS), [
        lang for lang, _ in BLOCKS
    ]


@pytest.mark.slow
@pytest.mark.parametrize("index", range(len(PYTHON)))
def test_python_block_runs(index, tmp_path):
    env = dict(os.environ, MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"))
    env["SCORBOT_GYM_CACHE"] = os.environ.get(
        "SCORBOT_GYM_CACHE", str(Path.home() / ".cache" / "scorbot-gym")
    )
    proc = subprocess.run(
        [sys.executable, "-c", PYTHON[index]],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, (
        f"README python block {index} failed:\n{PYTHON[index]}\n{proc.stderr[-3000:]}"
    )


@pytest.mark.parametrize("index", range(len(SHELL)))
def test_shell_block_commands_are_valid(index):
    from scorbot_gym.cli import build_parser

    parser = build_parser()
    for argv in _commands(SHELL[index]):
        if argv[0] == "scorbot-gym":
            parser.parse_args(argv[1:])  # SystemExit (with argparse's message) if not valid
        elif argv[0] == "python" and len(argv) > 1 and argv[1] != "-m":
            assert (ROOT / argv[1]).is_file(), f"README runs {argv[1]}, which does not exist"
        else:
            assert argv[0] in ("pip", "pytest", "MUJOCO_GL=egl", "export", "cd", "tensorboard"), (
                argv
            )
