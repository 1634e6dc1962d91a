"""Throughput of ``env.step`` on one pinned core, without images and with one 320x240 image per
step; with ``--peers``, side by side with FetchPickAndPlace-v4, Meta-World pick-place-v3 and
robosuite Lift (Panda) in the same run.

Run:  python benchmarks/env_step.py [--peers [--only-peers NAME ...] [--peer-venvs DIR]]
      [--repeats 5] [--cpu 0] [--out PATH.json] [--overwrite] [--config NAME]

By default the run is written to a new ``runs/env_step-<time>/env_step.json`` (and ``.png``);
``--out`` names another file, which is refused if it exists unless ``--overwrite`` is given.
``--config NAME`` stores the run as the variant ``configs[NAME]`` of ``--out`` (e.g. every peer,
another machine), without a figure; the file's other runs are kept. The committed main run is
rebuilt with ``python benchmarks/env_step.py --peers --only-peers FetchPickAndPlace-v4 --repeats
7 --out benchmarks/results/env_step.json --overwrite`` (a variant: ``--config NAME`` added).

Every environment is timed by the same loop, ``benchmarks/peers/time_env.py``, in a fresh
subprocess per repetition: scorbot-gym in this interpreter, each peer in its own virtual
environment under ``--peer-venvs`` (default ``~/.cache/scorbot-gym/peer-venvs/<name>``; built
on first use with ``python3 -m venv`` + pip from PyPI, reused while its pinned requirements are
unchanged). The
peers need mujoco 3.x; scorbot-gym runs on mujoco 4, so they cannot share one environment.

Repetitions interleave the environments (A, B, C, D, then D, C, B, A, ...) so that a change in
the machine's load hits all of them alike; every subprocess is pinned to the same core (the
affinity is inherited) and Mesa's llvmpipe is asked for one rendering thread. Medians over
repetitions are reported, with the load average before and after the run.

Every ratio is taken on CPU time (``time.process_time`` of the timing process, all its
threads: the rasterizer's too), within each repetition, then its median and range over the
repetitions are reported (``ratios``; the wall-clock ratio beside it): on a shared machine CPU
time moves much less with the load than wall time. Each frame's cost depends on what the
renderer draws, so the JSON records for every env its render settings (MSAA samples per pixel,
shadows, reflective materials), and the image ratio against FetchPickAndPlace is given as
shipped (ScorbotGrasp-v0 renders without MSAA, Fetch with MuJoCo's default 4x) and at matched
settings both ways (``FetchPickAndPlace-v4/msaa0``: Fetch's MSAA off; ``ScorbotGrasp-v0/msaa4``:
ours on). Neither renders shadows or reflections by default (``ScorbotGrasp-v0/shadows`` times
ours with its shadow map).

scorbot-gym is also timed with Cartesian actions (``ScorbotGrasp-v0/cartesian``: IK every
step, closed form as shipped; ``ScorbotGrasp-v0/cartesian_dls``: damped least squares every
step, as before 2026-11-28; without images), paired with joint actions in the same
repetitions; and ``profile``
breaks its step into stages (physics, task bookkeeping, observation, rendering, IK, the rest;
``time_env.py --profile``), the median over ``--repeats`` runs of each.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
TIMER = HERE / "peers" / "time_env.py"
SCORBOT = "ScorbotGrasp-v0"
# Its default renders without shadows; the peers render theirs (see render_settings in the JSON).
SCORBOT_SHADOWS = "ScorbotGrasp-v0/shadows"
SCORBOT_CARTESIAN = "ScorbotGrasp-v0/cartesian"
SCORBOT_CARTESIAN_DLS = "ScorbotGrasp-v0/cartesian_dls"  # every step by damped least squares
CARTESIAN = (SCORBOT_CARTESIAN, SCORBOT_CARTESIAN_DLS)  # timed without images only
# Fetch renders with MuJoCo's default 4x MSAA, ours without: each matched to the other
SCORBOT_MSAA4 = "ScorbotGrasp-v0/msaa4"
FETCH = "FetchPickAndPlace-v4"
FETCH_MSAA0 = "FetchPickAndPlace-v4/msaa0"
# variants that change what is rendered only: timed with an image alone
IMAGE_ONLY = (SCORBOT_SHADOWS, SCORBOT_MSAA4, FETCH_MSAA0)
# a peer's variants run in that peer's venv
PEER_VARIANTS = {FETCH_MSAA0: FETCH}
# The ratios the README quotes: (setting, comparison, numerator env, denominator env); each
# is the numerator's steps per CPU second over the denominator's, paired per repetition.
RATIOS = (
    ("no_images", "ScorbotGrasp-v0 / Fetch", SCORBOT, FETCH),
    ("camera_320x240", "ScorbotGrasp-v0 / Fetch, as shipped", SCORBOT, FETCH),
    ("camera_320x240", "ScorbotGrasp-v0 / Fetch, MSAA off in both", SCORBOT, FETCH_MSAA0),
    ("camera_320x240", "ScorbotGrasp-v0 / Fetch, 4x MSAA in both", SCORBOT_MSAA4, FETCH),
    ("no_images", "Cartesian / joint actions", SCORBOT_CARTESIAN, SCORBOT),
    ("no_images", "Cartesian (damped-least-squares IK) / joint actions", SCORBOT_CARTESIAN_DLS,
     SCORBOT),
)  # fmt: skip
# (env, setting) pairs profiled stage by stage
PROFILED = (
    (SCORBOT, "no_images"),
    (SCORBOT_CARTESIAN, "no_images"),
    (SCORBOT_CARTESIAN_DLS, "no_images"),
    (SCORBOT, "camera_320x240"),
)
VENV_ROOT = Path.home() / ".cache" / "scorbot-gym" / "peer-venvs"
# Each peer's venv and the pins it is built from (versions that install and run here).
PEERS: dict[str, dict] = {
    "FetchPickAndPlace-v4": {
        "venv": "gymnasium-robotics",
        "requirements": ["gymnasium-robotics==1.4.2", "gymnasium==1.4.0", "mujoco==3.3.0"],
    },
    "Meta-World/pick-place-v3": {
        "venv": "metaworld",
        # gymnasium's MuJoCo renderer imports `packaging`, which metaworld does not declare
        "requirements": ["metaworld==3.1.1", "gymnasium==1.4.0", "mujoco==3.3.0", "packaging"],
    },
    "robosuite/Lift-Panda": {
        "venv": "robosuite",
        "requirements": ["robosuite==1.5.2", "mujoco==3.3.0"],
    },
}
SETTINGS = {"no_images": False, "camera_320x240": True}
MARKER = "scorbot-peer-requirements.txt"


def peer_python(name: str, rebuild: bool = False, root: Path = VENV_ROOT) -> Path:
    """The interpreter of ``name``'s venv under ``root``, built if missing or built from other
    pins.

    The marker holding the pins is written last, so an interrupted build is never reused."""
    spec = PEERS[name]
    venv = root / spec["venv"]
    wanted = "\n".join(spec["requirements"]) + "\n"
    marker = venv / MARKER
    python = venv / "bin" / "python"
    if not rebuild and marker.is_file() and marker.read_text() == wanted:
        return python
    print(f"building peer venv {venv} ({', '.join(spec['requirements'])}) ...", flush=True)
    if venv.exists():
        shutil.rmtree(venv)
    subprocess.run(["python3", "-m", "venv", str(venv)], check=True)
    pip = [str(python), "-m", "pip", "install", "--quiet", "--disable-pip-version-check"]
    subprocess.run([*pip, *spec["requirements"]], check=True)
    marker.write_text(wanted)
    return python


def time_once(
    python: Path, env: str, image: bool, steps: int, seed: int, profile: bool = False
) -> dict:
    """One repetition: a fresh process runs the timing loop and prints its JSON line."""
    cmd = [str(python), str(TIMER), env, "--steps", str(steps), "--seed", str(seed)]
    if image:
        cmd.append("--image")
    if profile:
        cmd.append("--profile")
    proc = subprocess.run(cmd, capture_output=True, text=True, env=_child_env())
    if proc.returncode != 0:
        tail = proc.stderr.strip().splitlines()[-1:] or ["(no stderr)"]
        return {"error": f"exit {proc.returncode}: {tail[0]}"}
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _child_env() -> dict[str, str]:
    env = dict(os.environ)
    env.setdefault("MUJOCO_GL", "egl")
    env["LP_NUM_THREADS"] = "1"  # llvmpipe rasterizer threads: one core means one thread
    env["OMP_NUM_THREADS"] = env["MKL_NUM_THREADS"] = env["OPENBLAS_NUM_THREADS"] = "1"
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(HERE.parent), env.get("PYTHONPATH")]))
    return env


def _median(xs: list[float]) -> float:
    s = sorted(xs)
    n = len(s)
    return s[n // 2] if n % 2 else 0.5 * (s[n // 2 - 1] + s[n // 2])


def run(envs: dict[str, Path], repeats: int, steps: dict[str, int]) -> tuple[dict, list]:
    """Time every env in every setting, interleaved; return per-setting, per-env records and
    the :data:`RATIOS` the run has both envs of (:func:`paired_ratio`)."""
    runs: dict[str, dict[str, list[dict]]] = {s: {e: [] for e in envs} for s in SETTINGS}
    order = list(envs)
    for rep in range(repeats):
        for setting, image in SETTINGS.items():
            for env in order if rep % 2 == 0 else order[::-1]:
                if env in IMAGE_ONLY and not image:
                    continue  # identical to its base env when nothing is rendered
                if env in CARTESIAN and image:
                    continue  # the IK's cost is measured where it is not drowned by rendering
                r = time_once(envs[env], env, image, steps[setting], seed=rep)
                runs[setting][env].append(r)
                rate = r.get("steps_per_cpu_second")
                shown = f"{rate:8.1f} steps/CPU s" if rate else r.get("error")
                print(f"rep {rep} {setting:>14} {env:>28}: {shown}", flush=True)
    ratios = [
        {"setting": setting, "comparison": what, "numerator": a, "denominator": b,
         **paired_ratio(runs[setting][a], runs[setting][b])}
        for setting, what, a, b in RATIOS
        if runs[setting].get(a) and runs[setting].get(b)
    ]  # fmt: skip
    results: dict[str, dict] = {}
    for setting, per_env in runs.items():
        results[setting] = {}
        for env, rs in per_env.items():
            if not rs:
                continue
            ok = [r for r in rs if "steps_per_second" in r]
            if not ok:
                results[setting][env] = {"error": rs[-1]["error"]}
                continue
            med = _median([r["steps_per_second"] for r in ok])
            results[setting][env] = {
                "steps_per_second_median": med,
                "steps_per_second_runs": [r["steps_per_second"] for r in ok],
                "sim_seconds_per_step": ok[0]["sim_seconds_per_step"],
                "sim_seconds_per_wall_second_median": med * ok[0]["sim_seconds_per_step"],
                "steps_per_cpu_second_median": _median([r["steps_per_cpu_second"] for r in ok]),
                "steps_per_cpu_second_runs": [r["steps_per_cpu_second"] for r in ok],
                "steps_per_run": steps[setting],
                "failed_runs": len(rs) - len(ok),
                "note": ok[0]["note"],
                "render_settings": ok[0]["render_settings"],
                "versions": ok[0]["versions"],
            }
    return results, ratios


def profile(python: Path, repeats: int, steps: dict[str, int]) -> dict:
    """Stage-by-stage timing of scorbot's step (``time_env.py --profile``): per (env, setting),
    the median over ``repeats`` fresh processes of each stage's mean microseconds per step."""
    out: dict[str, dict] = {}
    for env, setting in PROFILED:
        runs = []
        for rep in range(repeats):
            r = time_once(python, env, SETTINGS[setting], steps[setting], rep, profile=True)
            if "error" in r:
                print(f"profile {env} {setting}: {r['error']}", flush=True)
                continue
            runs.append(r)
        if not runs:
            continue
        parts = {k: _median([r["parts_us"].get(k, 0.0) for r in runs]) for k in runs[0]["parts_us"]}
        step_us = _median([r["step_us"] for r in runs])
        out[f"{env} {setting}"] = {
            "step_us_median": step_us,
            "parts_us_median": parts,
            "physics_share_median": _median([r["physics_share"] for r in runs]),
            "physics_share_runs": [r["physics_share"] for r in runs],
            "runs": len(runs),
        }
        print(f"profile {env} {setting}: {step_us:.0f} us/step, physics share "
              f"{out[f'{env} {setting}']['physics_share_median']:.0%}", flush=True)  # fmt: skip
    return out


def paired_ratio(ours: list[dict], theirs: list[dict]) -> dict:
    """``ours`` over ``theirs`` in steps per CPU second, run against run of the same repetition
    (next to each other in time, so under about the same load): the median, range and every
    pair; the wall-clock ratio beside it, and each side's render settings."""
    pairs = [
        (a, b)
        for a, b in zip(ours, theirs, strict=False)
        if "steps_per_cpu_second" in a and "steps_per_cpu_second" in b
    ]
    if not pairs:
        return {"pairs": 0}
    cpu = [a["steps_per_cpu_second"] / b["steps_per_cpu_second"] for a, b in pairs]
    wall = [a["steps_per_second"] / b["steps_per_second"] for a, b in pairs]
    return {
        "pairs": len(pairs),
        "cpu_ratio_median": _median(cpu),
        "cpu_ratio_min": min(cpu),
        "cpu_ratio_max": max(cpu),
        "cpu_ratio_runs": cpu,
        "wall_ratio_median": _median(wall),
        "wall_ratio_runs": wall,
        "render_settings": {
            "numerator": pairs[0][0]["render_settings"],
            "denominator": pairs[0][1]["render_settings"],
        },
    }


def plot(report: dict, path: Path) -> None:
    """Per setting, every env's steps per wall second and per CPU second (log scale)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from pose.fileio import atomic_write

    settings = list(report["results"])
    fig, axes = plt.subplots(1, len(settings), figsize=(5.5 * len(settings), 4.2))
    for ax, setting in zip(axes, settings, strict=True):
        items = [(env, r) for env, r in report["results"][setting].items() if "error" not in r]
        x = np.arange(len(items))
        for dx, key, label, color in (
            (-0.2, "steps_per_second_median", "per wall second", "#3a78b5"),
            (0.2, "steps_per_cpu_second_median", "per CPU second", "#e08a2c"),
        ):
            ax.bar(x + dx, [r[key] for _, r in items], width=0.4, label=label, color=color)
        ax.set_xticks(x, [env.replace("/", "/\n") for env, _ in items], rotation=30, ha="right")
        ax.set_yscale("log")
        ax.set_title(setting.replace("_", " "))
        ax.set_ylabel("env steps (one pinned core, median)")
        ax.tick_params(axis="x", labelsize=7)
        ax.legend(fontsize=8)
    fig.tight_layout()
    atomic_write(path, lambda f: fig.savefig(f, dpi=100, format="png"))
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--peers", action="store_true", help="also time the peer envs")
    parser.add_argument(
        "--only-peers", nargs="+", choices=sorted(PEERS), help="with --peers: just these peers"
    )
    parser.add_argument("--rebuild-peers", action="store_true", help="rebuild the peer venvs")
    parser.add_argument(
        "--peer-venvs",
        type=Path,
        default=VENV_ROOT,
        help=f"where the peers' venvs are built and kept (default {VENV_ROOT})",
    )
    parser.add_argument("--steps", type=int, default=2000, help="timed steps without images")
    parser.add_argument("--image-steps", type=int, default=200, help="timed steps with images")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--cpu", type=int, default=0, help="core to pin to")
    from scorbot_gym.experiments.outputs import Outputs, add_overwrite_option

    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        help="where to write (default: runs/env_step-<time>/env_step.json; an existing "
        "file is refused without --overwrite)",
    )
    add_overwrite_option(parser)
    parser.add_argument(
        "--config",
        default=None,
        help="store the run as this named variant of --out (default: the file's main run)",
    )
    args = parser.parse_args(argv)
    try:  # before any work: an existing file is not replaced unless asked
        args.out = Outputs("env_step", args.overwrite).path(
            args.out, "env_step.json", "--out", companions=[".png"] if args.config is None else []
        )
    except ValueError as exc:
        parser.error(str(exc))
    if args.steps < 1 or args.image_steps < 1 or args.repeats < 1:
        parser.error("--steps, --image-steps and --repeats must be >= 1")
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {args.cpu})  # inherited by every timing subprocess

    import scorbot_gym
    from pose.fileio import write_result

    ours = Path(sys.executable)
    envs = {
        SCORBOT: ours,
        SCORBOT_CARTESIAN: ours,
        SCORBOT_CARTESIAN_DLS: ours,
        SCORBOT_SHADOWS: ours,
        SCORBOT_MSAA4: ours,
    }
    if args.peers:
        peers = args.only_peers or list(PEERS)
        envs.update({n: peer_python(n, args.rebuild_peers, args.peer_venvs) for n in peers})
        envs.update({v: envs[base] for v, base in PEER_VARIANTS.items() if base in envs})
    load_before = os.getloadavg()
    t0 = time.time()
    steps = {"no_images": args.steps, "camera_320x240": args.image_steps}
    results, ratios = run(envs, args.repeats, steps)
    profiles = profile(ours, args.repeats, steps)
    report = {
        "benchmark": "env_step",
        "envs": list(envs),
        "loop": "benchmarks/peers/time_env.py: uniform random actions, step (+ one 320x240 RGB "
        "image) timed, resets not timed; one fresh process per env, setting and repetition",
        "one_core": True,
        "pinned_cpu": args.cpu,
        "repeats": args.repeats,
        "interleaved": "A,B,C,D then D,C,B,A ... per setting",
        "ratios_how": "steps per CPU second (time.process_time of the timing process, all its "
        "threads) of the numerator over the denominator, run against run of the same "
        "repetition; median and range over the repetitions (wall-clock ratio beside it)",
        "ratios": ratios,
        "results": results,
        "profile": {
            "how": "benchmarks/peers/time_env.py --profile: the env's stages timed in place, "
            "mean us per step over the timed steps; median over repeats (fresh processes)",
            "physics": "MuJoCo mj_step (frame_skip substeps)",
            "results": profiles,
        },
        "load": {
            "loadavg_before": load_before,
            "loadavg_after": os.getloadavg(),
            "wall_seconds": time.time() - t0,
            "note": "the machine is shared; loadavg counts other users' processes too",
        },
        "peer_requirements": {n: PEERS[n]["requirements"] for n in envs if n in PEERS},
        "peer_variants": {v: b for v, b in PEER_VARIANTS.items() if v in envs},
        "machine": {
            "platform": platform.platform(),
            "python": sys.version.split()[0],
            "cpu_count": os.cpu_count(),
            "scorbot_gym": scorbot_gym.__version__,
            "mujoco_gl": os.environ.get("MUJOCO_GL", "egl"),
        },
    }
    write_result(args.out, report, args.config)
    if args.config is None:  # the figure is the main run's
        plot(report, args.out.with_suffix(".png"))
    for setting, per_env in results.items():
        for env, r in per_env.items():
            shown = r.get("error") or f"{r['steps_per_cpu_second_median']:8.1f} steps/CPU s"
            print(f"{setting:>14} {env:>28}: {shown}")
    for r in ratios:
        if r["pairs"]:
            print(f"{r['setting']:>14} {r['comparison']}: {r['cpu_ratio_median']:.2f}x per CPU "
                  f"second ({r['cpu_ratio_min']:.2f}-{r['cpu_ratio_max']:.2f}, {r['pairs']} "
                  f"pairs; wall {r['wall_ratio_median']:.2f}x)")  # fmt: skip
    figure = f" and {args.out.with_suffix('.png')}" if args.config is None else ""
    print(f"written {args.out}{figure}" + (f" (config {args.config!r})" if args.config else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
