"""Memory footprint and reset cost of one ``ScorbotGrasp-v0`` env over the whole catalogue.

Each configuration runs in a fresh Python process (RSS is per process), which makes the env,
resets once onto every catalogue object (the cold start: every scene is compiled on its first
reset, and a vector env pays this again in each subprocess), then resets ``--resets`` more times
onto random objects (the steady state). Reported: resident memory (VmRSS) after import, after
``make``, after the catalogue pass and at the end; the first-reset (compile) times; the median
and 90th-percentile steady-state reset times, split by whether the reset switched scenes, as
wall time and as the process's CPU time (all its threads, software GL's included), which other
load on a shared machine inflates much less. With a camera, every reset renders the first
observation's frame; the same frame is rendered once more after each reset and timed alone
(``frame_cpu_ms``), so that the reset's own cost can be told from the image's. Resident memory
is split into anonymous (heap: models, GL state) and file-backed (shared libraries) pages.
The objects' derived geometry is read from the on-disk cache, as on every run after the first;
one configuration starts from an empty cache folder to show the first run's footprint.

    python benchmarks/env_memory.py                  # writes runs/env_memory-<time>/env_memory.json
    python benchmarks/env_memory.py --out benchmarks/results/env_memory.json --overwrite  # record
    python benchmarks/env_memory.py --resets 50 --out /tmp/m.json

Linux only (reads /proc/self/status).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

_CAMERA = {"cameras": ["top"], "image_width": 320, "image_height": 240}
CONFIGS = {
    "no_camera": {},
    "camera_top_320x240": _CAMERA,
    # The same with an empty cache folder, as on the first run after installing or upgrading:
    # each object's geometry is derived (trimesh, scipy) in a short-lived child process.
    "camera_top_320x240_cold_object_cache": _CAMERA,
}


def _rss_mb(field: str = "VmRSS") -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(field + ":"):
                return int(line.split()[1]) / 1024.0
    raise RuntimeError(f"{field} not in /proc/self/status")


def _median(xs: list[float]) -> float:
    s = sorted(xs)
    n = len(s)
    return s[n // 2] if n % 2 else 0.5 * (s[n // 2 - 1] + s[n // 2])


def _quantile(xs: list[float], q: float) -> float:
    s = sorted(xs)
    return s[min(len(s) - 1, int(q * len(s)))]


def worker(config: str, resets: int, seed: int) -> dict:
    """Measure one configuration in this process (run by :func:`main` in a subprocess)."""
    t0 = time.perf_counter()
    import gymnasium as gym

    import scorbot_gym  # noqa: F401  (registers the ids)
    from scorbot_gym.objects import CATALOGUE

    rss_import, t_import = _rss_mb(), time.perf_counter() - t0
    t0 = time.perf_counter()
    env = gym.make("ScorbotGrasp-v0", **CONFIGS[config])
    t_make, rss_make = time.perf_counter() - t0, _rss_mb()
    first = {}
    for i, name in enumerate(CATALOGUE):
        t0 = time.perf_counter()
        env.reset(seed=seed + i, options={"object_name": name})
        first[name] = time.perf_counter() - t0
    rss_catalogue = _rss_mb()
    rss_split = {k: _rss_mb(k) for k in ("RssAnon", "RssFile")}
    switch, same, cpu, frame = [], [], [], []
    cameras = CONFIGS[config].get("cameras", [])
    current = env.unwrapped.sim.object_spec.name
    for i in range(resets):
        c0, t0 = time.process_time(), time.perf_counter()
        _, info = env.reset(seed=seed + 1000 + i)
        dt, cpu_dt = time.perf_counter() - t0, time.process_time() - c0
        if cameras:  # the observation's frame again, alone
            c0 = time.process_time()
            env.unwrapped.sim.render(cameras[0])
            frame.append(time.process_time() - c0)
        (same if info["object_name"] == current else switch).append(dt)
        cpu.append((info["object_name"] != current, cpu_dt))
        current = info["object_name"]
    env.close()
    ms = 1e3
    all_resets = switch + same
    cpu_switch = [c for switched, c in cpu if switched]
    cpu_same = [c for switched, c in cpu if not switched]
    return {
        "config": CONFIGS[config],
        "objects": len(CATALOGUE),
        "rss_mb": {
            "after_import": round(rss_import, 1),
            "after_make": round(rss_make, 1),
            "after_catalogue_pass": round(rss_catalogue, 1),
            "after_catalogue_pass_anonymous": round(rss_split["RssAnon"], 1),
            "after_catalogue_pass_file_backed": round(rss_split["RssFile"], 1),
            "end": round(_rss_mb(), 1),
            "peak": round(_rss_mb("VmHWM"), 1),
        },
        "cold_start_s": {
            "import": round(t_import, 3),
            "make": round(t_make, 3),
            "first_resets_total": round(sum(first.values()), 3),
            "first_reset_median": round(_median(list(first.values())), 3),
            "first_reset_max": round(max(first.values()), 3),
        },
        "steady_reset_ms": {
            "resets": len(all_resets),
            "median": round(ms * _median(all_resets), 3),
            "p90": round(ms * _quantile(all_resets, 0.9), 3),
            "median_switching_scene": round(ms * _median(switch), 3) if switch else None,
            "median_same_scene": round(ms * _median(same), 3) if same else None,
            "switches": len(switch),
        },
        "steady_reset_cpu_ms": {
            "median": round(ms * _median([c for _, c in cpu]), 3),
            "median_switching_scene": round(ms * _median(cpu_switch), 3) if cpu_switch else None,
            "median_same_scene": round(ms * _median(cpu_same), 3) if cpu_same else None,
        },
        "frame_cpu_ms": {"median": round(ms * _median(frame), 3)} if frame else None,
    }


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--resets", type=int, default=300, help="steady-state resets per config")
    p.add_argument("--seed", type=int, default=0)
    from scorbot_gym.experiments.outputs import Outputs, add_overwrite_option

    p.add_argument(
        "--out",
        type=Path,
        default=None,
        help="where to write (default: runs/env_memory-<time>/env_memory.json; an existing "
        "file is refused without --overwrite)",
    )
    add_overwrite_option(p)
    p.add_argument("--label", default="", help="what code was measured (stored in the JSON)")
    p.add_argument("--worker", choices=sorted(CONFIGS), help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    try:  # before any work: an existing file is not replaced unless asked
        args.out = Outputs("env_memory", args.overwrite).path(args.out, "env_memory.json", "--out")
    except ValueError as exc:
        p.error(str(exc))
    if args.resets < 1:
        p.error(f"--resets must be >= 1, got {args.resets}")
    if args.worker:
        print(json.dumps(worker(args.worker, args.resets, args.seed)))
        return {}
    warm = "from scorbot_gym.objects import CATALOGUE; [s.model for s in CATALOGUE.values()]"
    subprocess.run([sys.executable, "-c", warm], check=True)  # fills the object cache
    results = {}
    for name in CONFIGS:
        cmd = [sys.executable, __file__, "--worker", name, "--resets", str(args.resets)]
        cmd += ["--seed", str(args.seed)]
        with tempfile.TemporaryDirectory() as empty:
            env = dict(os.environ)
            if name.endswith("_cold_object_cache"):
                env["SCORBOT_GYM_CACHE"] = empty
            out = subprocess.run(cmd, check=True, capture_output=True, text=True, env=env).stdout
        results[name] = json.loads(out.strip().splitlines()[-1])
        print(name, json.dumps(results[name], indent=1))
    report = {
        "benchmark": "env_memory",
        "label": args.label,
        "machine": {
            "cpu_count": os.cpu_count(),
            "load_average_1min_at_start": round(os.getloadavg()[0], 2),
            "platform": platform.platform(),
            "MUJOCO_GL": os.environ.get("MUJOCO_GL", ""),
        },
        "resets": args.resets,
        "seed": args.seed,
        "results": results,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.out.with_suffix(".tmp")
    tmp.write_text(json.dumps(report, indent=2) + "\n")
    os.replace(tmp, args.out)
    return report


if __name__ == "__main__":
    main()
