"""Start-up cost of the ``scorbot-gym`` command line, and of the GL preload.

Each command runs ``--runs`` times in a fresh interpreter (``python -m scorbot_gym.cli ...``);
reported per command: the median wall time, its exit code, and which of torch, SB3, OpenCV,
MuJoCo, dm_control, scikit-learn and ``scipy.stats`` the command imported (a second process,
the same arguments, lists ``sys.modules``): ``--help`` and argument errors, of every
sub-command too, should import none of them. ``--baseline DIR`` times another
checkout's package the same way, command by command in the same run (the machine's load is
shared, so compare the two columns, not runs). The GL preload
(``scorbot_gym._gl.preload_bundled_llvm``: loading triton's ``libtriton.so`` before the first GL
context, where triton is installed) is timed in its own fresh processes, with the private
(dirty) memory of the libraries it loaded: none where triton is not installed (the CPU build of
torch).

    python benchmarks/cli_startup.py              # writes runs/cli_startup-<time>/cli_startup.json
    python benchmarks/cli_startup.py --runs 9 --baseline DIR_OF_AN_OLDER_CHECKOUT \\
        --out benchmarks/results/cli_startup.json --overwrite   # the committed record
    python benchmarks/cli_startup.py --runs 3 --out /tmp/cli.json
    mkdir /tmp/before && git archive febf072 | tar -x -C /tmp/before
    python benchmarks/cli_startup.py --baseline /tmp/before   # the same commands, side by side
    python benchmarks/cli_startup.py --preload-only --config gl_preload_cuda \\
        --out benchmarks/results/cli_startup.json --overwrite   # (CUDA torch venv)
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pose.fileio import write_result  # noqa: E402

COMMANDS = (
    ("--help",),
    ("teleport",),  # an unknown command: an argument error
    ("rollout", "--help"),
    ("rollout", "--episodes", "0"),  # a sub-command's argument error
    ("train", "--help"),
    ("train", "--algo", "dqn"),
    ("compare", "--help"),
    ("compare", "--episodes", "0"),
    ("pose", "ablate", "--help"),
    ("pose", "ablate", "--jobs", "0"),
    ("pose", "train", "--help"),
    ("pose", "train", "--camera", "ceiling"),
    ("shapes", "eval", "--help"),
    ("demos", "--help"),
    ("demos", "--out", "x", "--episodes", "0"),
    ("doctor", "--help"),
)
HEAVY = ("torch", "stable_baselines3", "cv2", "mujoco", "dm_control", "sklearn", "scipy.stats")

_IMPORTED = f"""
import sys
from scorbot_gym.cli import main
try:
    main(sys.argv[1:])
except SystemExit:
    pass
print("imported:" + ",".join(m for m in {HEAVY!r} if m in sys.modules))
"""

_PRELOAD = """
import json, time
from scorbot_gym import _gl

def private_dirty_mb(paths):
    total, inside = 0, False
    for line in open("/proc/self/smaps"):
        if line[0] in "0123456789abcdef" and "-" in line.split()[0]:
            inside = line.split()[-1] in paths
        elif inside and line.startswith("Private_Dirty:"):
            total += int(line.split()[1])
    return total / 1024

t0 = time.perf_counter()
loaded = _gl.preload_bundled_llvm()
ms = 1e3 * (time.perf_counter() - t0)
print(json.dumps({"ms": ms, "loaded": loaded, "private_dirty_mb": private_dirty_mb(loaded)}))
"""


def time_command(argv: tuple[str, ...], runs: int, checkout: Path = ROOT) -> dict:
    """``argv`` run ``runs`` times with the package of ``checkout``; and what it imported."""
    env = {**os.environ, "PYTHONPATH": str(checkout)}
    cli = [sys.executable, "-m", "scorbot_gym.cli", *argv]
    times, codes = [], set()
    for _ in range(runs):
        t0 = time.perf_counter()
        proc = subprocess.run(cli, capture_output=True, cwd=checkout, env=env)
        times.append(time.perf_counter() - t0)
        codes.add(proc.returncode)
    probe = [sys.executable, "-c", _IMPORTED, *argv]
    out = subprocess.run(probe, capture_output=True, text=True, cwd=checkout, env=env).stdout
    marked = [ln.removeprefix("imported:") for ln in out.splitlines() if ln.startswith("imported:")]
    return {
        "argv": " ".join(argv),
        "median_s": round(statistics.median(times), 3),
        "min_s": round(min(times), 3),
        "exit_codes": sorted(codes),
        "heavy_imports": [m for m in (marked[-1] if marked else "").split(",") if m],
    }


def time_preload(runs: int) -> dict:
    rows = []
    for _ in range(runs):
        proc = subprocess.run(
            [sys.executable, "-c", _PRELOAD], capture_output=True, text=True, cwd=ROOT, check=True
        )
        rows.append(json.loads(proc.stdout.strip().splitlines()[-1]))
    return {
        "median_ms": round(statistics.median(r["ms"] for r in rows), 2),
        # memory of its own (relocations); the library's code pages are shared page cache
        "private_dirty_mb": round(statistics.median(r["private_dirty_mb"] for r in rows), 1),
        "loaded": [Path(p).name for p in rows[0]["loaded"]],
    }


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5, help="fresh processes per command (median)")
    from scorbot_gym.experiments.outputs import Outputs, add_overwrite_option

    ap.add_argument(
        "--out",
        type=Path,
        default=None,
        help="where to write (default: runs/cli_startup-<time>/cli_startup.json; an existing "
        "file is refused without --overwrite)",
    )
    add_overwrite_option(ap)
    ap.add_argument(
        "--config",
        default=None,
        help="store the run as this named variant of --out (default: the file's main run)",
    )
    ap.add_argument(
        "--baseline",
        type=Path,
        default=None,
        help="another checkout (e.g. `git archive` of an older commit) timed alongside, "
        "command by command, in the same run",
    )
    ap.add_argument(
        "--preload-only",
        action="store_true",
        help="time the GL preload only (e.g. in a venv with the CUDA build of torch and triton)",
    )
    args = ap.parse_args(argv)
    try:  # before any work: an existing file is not replaced unless asked
        args.out = Outputs("cli_startup", args.overwrite).path(
            args.out, "cli_startup.json", "--out"
        )
    except ValueError as exc:
        ap.error(str(exc))
    commands = []
    # the baseline interleaved, command by command: both see the same machine load
    for command in () if args.preload_only else COMMANDS:
        row = time_command(command, args.runs)
        if args.baseline is not None:
            base = time_command(command, args.runs, args.baseline)
            row["baseline"] = {k: base[k] for k in ("median_s", "exit_codes", "heavy_imports")}
        commands.append(row)
        was = f"  (baseline {row['baseline']['median_s']:.2f} s)" if "baseline" in row else ""
        print(
            f"scorbot-gym {row['argv']:<32} {row['median_s']:6.2f} s{was}  {row['heavy_imports']}"
        )
    preload = time_preload(args.runs)
    print(f"GL preload: {preload['median_ms']:.1f} ms, loaded {preload['loaded'] or 'nothing'}")
    result = {
        "runs": args.runs,
        "baseline": None if args.baseline is None else str(args.baseline),
        "python": platform.python_version(),
        "machine": platform.machine(),
        "commands": commands,
        "gl_preload": preload,
    }
    write_result(args.out, result, args.config)
    print(f"wrote {args.out}" + (f" (config {args.config!r})" if args.config else ""))
    return result


if __name__ == "__main__":
    main()
