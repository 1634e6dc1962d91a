"""Every README example runs as a user runs it.

Each ``python`` block is saved as a script in an empty temporary folder and run there by a fresh
interpreter (``python example.py``, not ``python -c``: a script that starts worker processes
with ``context="spawn"`` needs its ``if __name__ == "__main__":`` guard, and only a saved file
shows whether it has one). Each ``bash`` block is run command by command in such a folder too,
``scorbot-gym`` through this interpreter. ``shell`` blocks are the commands too long for a test
(installing, the test suite, full benchmark runs): their ``scorbot-gym`` commands must parse
with the real argument parser and their ``python <script>`` must name a script that exists.
Nothing an example writes may land in the repository.
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
BASH = [code for lang, code in BLOCKS if lang == "bash"]
SHELL = [code for lang, code in BLOCKS if lang == "shell"]
MAX_LINES = 400  # the README is what a user reads; results live in benchmarks/README.md


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


def _env() -> dict[str, str]:
    """The test's environment, with the repository importable and the shared model cache (the
    examples' pose models are trained once per machine, as for a user)."""
    env = dict(os.environ, MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"))
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), *filter(None, [env.get("PYTHONPATH")])])
    env.setdefault("SCORBOT_GYM_CACHE", str(Path.home() / ".cache" / "scorbot-gym"))
    return env


def _run(argv: list[str], cwd: Path, what: str) -> None:
    before = set(ROOT.iterdir())
    proc = subprocess.run(
        argv, cwd=cwd, env=_env(), capture_output=True, text=True, timeout=900
    )  # fmt: skip
    assert proc.returncode == 0, f"README {what} failed:\n{proc.stderr[-3000:]}"
    assert set(ROOT.iterdir()) == before, f"README {what} wrote into the repository"


def test_readme_is_short_and_has_runnable_blocks():
    assert len(README.splitlines()) <= MAX_LINES
    assert len(PYTHON) >= 5 and len(BASH) >= 3 and len(SHELL) >= 2
    assert all(lang in ("python", "bash", "shell") for lang, _ in BLOCKS), [
        lang for lang, _ in BLOCKS
    ]
    # the CI runs exactly this test command; the README must give it verbatim
    assert 'pip install -e ".[test]" && pytest' in "".join(SHELL)


@pytest.mark.slow
@pytest.mark.parametrize("index", range(len(PYTHON)))
def test_python_block_runs_as_a_saved_script(index, tmp_path):
    script = tmp_path / "example.py"
    script.write_text(PYTHON[index])
    _run([sys.executable, script.name], tmp_path, f"python block {index}:\n{PYTHON[index]}")


@pytest.mark.slow
@pytest.mark.parametrize("index", range(len(BASH)))
def test_bash_block_runs(index, tmp_path):
    for argv in _commands(BASH[index]):
        assert argv[0] == "scorbot-gym", f"a bash block runs scorbot-gym only, got {argv}"
        _run([sys.executable, "-m", "scorbot_gym.cli", *argv[1:]], tmp_path, shlex.join(argv))


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
            assert argv[0] in ("pip", "pytest", "pdoc"), argv


def _api_rows() -> list[tuple[str, list[str], list[str]]]:
    """The rows of the README's "The API in brief" table: (the row's text, the modules its
    second column names, the backticked entries of its first column). ``.x`` in the second
    column is a submodule of the first module named there."""
    section = README.split("## The API in brief", 1)[1].split("\n## ", 1)[0]
    rows = []
    for line in section.splitlines():
        cells = [c.strip() for c in re.split(r"(?<!\\)\|", line)[1:-1]]
        if len(cells) != 2 or cells[0] in ("what", "---"):
            continue
        where = re.findall(r"`([\w.]+)`", cells[1])
        base = where[0]
        modules = [base + m if m.startswith(".") else m for m in where]
        rows.append((line, modules, re.findall(r"`([^`]+)`", cells[0])))
    return rows


API_ROWS = _api_rows()


def test_the_api_table_parses():
    assert len(API_ROWS) >= 10, API_ROWS  # the table is there and was read
    assert all(modules for _, modules, _ in API_ROWS)


@pytest.mark.parametrize("row", API_ROWS, ids=[r[1][0] for r in API_ROWS])
def test_the_api_table_names_import_from_the_modules_it_gives(row):
    """Each name in the table imports from one of the modules its row gives (``from MODULE
    import NAME``), an attribute path (``ScriptedGraspPolicy.for_env``) resolves, and a call
    written with literal arguments only (``RolloutConfig(pose="manifold", estimator="chance")``)
    runs as written."""
    import ast
    import importlib
    import inspect

    line, modules, entries = row
    loaded = [importlib.import_module(m) for m in modules]
    for entry in entries:
        m = re.match(r"^([A-Za-z_]\w*(?:\.[A-Za-z_]\w*)*)(\(.*\))?$", entry.replace("\\|", "|"))
        if m is None:  # an env id, a keyword value: not a name
            continue
        head, *attrs = m.group(1).split(".")
        # a submodule of the same name (``evaluation.compare``) is not the function named
        owners = [mod for mod in loaded if not inspect.ismodule(getattr(mod, head, inspect))]
        assert owners, f"{head!r} imports from none of {modules} (README row: {line})"
        obj = getattr(owners[0], head)
        for attr in attrs:
            obj = getattr(obj, attr)
        try:
            call = ast.parse(entry.replace("\\|", "|"), mode="eval").body
        except SyntaxError:  # `name(a="x"|"y", ...)`: a signature sketch, not a call
            continue
        if not isinstance(call, ast.Call):
            continue
        values = [*call.args, *(k.value for k in call.keywords)]
        literal = all(
            isinstance(v, ast.Constant) and v.value is not Ellipsis for v in values
        ) and all(k.arg is not None for k in call.keywords)
        if values and literal:  # as written, it must run
            obj(*[v.value for v in call.args], **{k.arg: k.value.value for k in call.keywords})
