"""Throughput of ``env.step`` on one pinned core, without images and with one 320x240 image per
step; with ``--peers``, side by side with FetchPickAndPlace-v4, Meta-World pick-place-v3 and
robosuite Lift (Panda) in the same run.

Run:  python benchmarks/env_step.py [--peers [--only-peers NAME ...]] [--repeats 5] [--cpu 0]
      [--out PATH.json] [--config NAME]

By default the run is written to a new ``runs/env_step-<time>/env_step.json`` (and ``.png``);
``--out`` names another file, which is refused if it exists unless ``--overwrite`` is given.
``--config NAME`` stores the run as the variant ``configs[NAME]`` of ``--out`` (e.g. every peer,
another machine), without a figure; the file's other runs are kept. The committed record is
rebuilt with ``python benchmarks/env_step.py --peers --out benchmarks/results/env_step.json
--overwrite`` (a variant of it: ``--config NAME`` added).

Every environment is timed by the same loop, ``benchmarks/peers/time_env.py``, in a fresh
subprocess per repetition: scorbot-gym in this interpreter, each peer in its own virtual
environment under ``~/.cache/scorbot-gym/peer-venvs/<name>`` (built on first use with
``python3 -m venv`` + pip from PyPI, reused while its pinned requirements are unchanged). The
peers need mujoco 3.x; scorbot-gym runs on mujoco 4, so they cannot share one environment.

Repetitions interleave the environments (A, B, C, D, then D, C, B, A, ...) so that a change in
the machine's load hits all of them alike; every subprocess is pinned to the same core (the
affinity is inherited) and Mesa's llvmpipe is asked for one rendering thread. Medians over
repetitions are reported, with the load average before and after the run.

scorbot-gym is also timed with Cartesian actions (``ScorbotGrasp-v0/cartesian``: IK every
step; without images), paired with joint actions in the same repetitions; and ``profile``
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
# (env, setting) pairs profiled stage by stage
PROFILED = ((SCORBOT, "no_images"), (SCORBOT_CARTESIAN, "no_images"), (SCORBOT, "camera_320x240"))
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


def peer_python(name: str, rebuild: bool = False) -> Path:
    """The interpreter of ``name``'s venv, built if missing or built from other pins.

    The marker holding the pins is written last, so an interrupted build is never reused."""
    spec = PEERS[name]
    venv = VENV_ROOT / spec["venv"]
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


def run(envs: dict[str, Path], repeats: int, steps: dict[str, int]) -> dict:
    """Time every env in every setting, interleaved; return per-setting, per-env records."""
    runs: dict[str, dict[str, list[dict]]] = {s: {e: [] for e in envs} for s in SETTINGS}
    order = list(envs)
    for rep in range(repeats):
        for setting, image in SETTINGS.items():
            for env in order if rep % 2 == 0 else order[::-1]:
                if env == SCORBOT_SHADOWS and not image:
                    continue  # identical to SCORBOT when nothing is rendered
                if env == SCORBOT_CARTESIAN and image:
                    continue  # the IK's cost is measured where it is not drowned by rendering
                r = time_once(envs[env], env, image, steps[setting], seed=rep)
                runs[setting][env].append(r)
                rate = r.get("steps_per_second")
                shown = f"{rate:8.1f} steps/s" if rate else r.get("error")
                print(f"rep {rep} {setting:>14} {env:>26}: {shown}", flush=True)
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
                "steps_per_run": steps[setting],
                "failed_runs": len(rs) - len(ok),
                "note": ok[0]["note"],
                "render_settings": ok[0]["render_settings"],
                "versions": ok[0]["versions"],
            }
        for ours_name, prefix in ((SCORBOT, "scorbot"), (SCORBOT_SHADOWS, "scorbot_shadows")):
            for env, r in results[setting].items():
                if not env.startswith(SCORBOT) and "steps_per_second_median" in r:
                    r.update(_paired_ratios(per_env.get(ours_name, []), per_env[env], prefix))
        cartesian = results[setting].get(SCORBOT_CARTESIAN, {})
        if "steps_per_second_median" in cartesian:  # Cartesian over joint actions
            pairs = _paired_ratios(per_env[SCORBOT_CARTESIAN], per_env[SCORBOT], "vs_joint")
            cartesian.update(pairs)
    return results


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


def _paired_ratios(ours: list[dict], theirs: list[dict], prefix: str) -> dict:
    """Ratios of runs taken in the same repetition (next to each other in time, so under about
    the same load), then their median: steadier than a ratio of medians on a busy machine."""
    pairs = [
        (a, b)
        for a, b in zip(ours, theirs, strict=False)
        if "steps_per_second" in a and "steps_per_second" in b
    ]
    if not pairs:
        return {}
    ratios = [a["steps_per_second"] / b["steps_per_second"] for a, b in pairs]
    cpu = [a["steps_per_cpu_second"] / b["steps_per_cpu_second"] for a, b in pairs]
    dt = pairs[0][0]["sim_seconds_per_step"] / pairs[0][1]["sim_seconds_per_step"]
    return {
        f"{prefix}_ratio_steps_per_second": _median(ratios),
        f"{prefix}_ratio_steps_per_second_runs": ratios,
        f"{prefix}_ratio_sim_seconds_per_wall_second": _median(ratios) * dt,
        f"{prefix}_ratio_steps_per_cpu_second": _median(cpu),
        f"{prefix}_ratio_steps_per_cpu_second_runs": cpu,
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
    envs = {SCORBOT: ours, SCORBOT_CARTESIAN: ours, SCORBOT_SHADOWS: ours}
    if args.peers:
        peers = args.only_peers or list(PEERS)
        envs.update({name: peer_python(name, args.rebuild_peers) for name in peers})
    load_before = os.getloadavg()
    t0 = time.time()
    steps = {"no_images": args.steps, "camera_320x240": args.image_steps}
    results = run(envs, args.repeats, steps)
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
            ratio = r.get("scorbot_ratio_steps_per_second") or r.get(
                "vs_joint_ratio_steps_per_second"
            )
            cpu = r.get("scorbot_ratio_steps_per_cpu_second") or r.get(
                "vs_joint_ratio_steps_per_cpu_second"
            )
            who = "cartesian/joint" if env == SCORBOT_CARTESIAN else "scorbot"
            extra = f"  ({who} {ratio:.2f}x, per CPU second {cpu:.2f}x)" if ratio else ""
            shown = r.get("error") or f"{r['steps_per_second_median']:8.1f} steps/s"
            print(f"{setting:>14} {env:>26}: {shown}{extra}")
    figure = f" and {args.out.with_suffix('.png')}" if args.config is None else ""
    print(f"written {args.out}{figure}" + (f" (config {args.config!r})" if args.config else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
