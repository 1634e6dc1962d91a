"""Throughput of ``env.step`` on one core, without images and with one 320x240 image per step.

Run:  python benchmarks/env_step.py [--steps 2000] [--repeats 5] [--out PATH.json]

The process pins itself to one CPU core and asks Mesa's llvmpipe for one rendering thread, so
the figure is a one-core figure. Only ``env.step`` calls are timed (resets are not); each repeat
is one timed block, and the median over repeats is reported.

Reference: Gymnasium-Robotics' FetchPickAndPlace-v4 measured on this machine type on one core
(issue #2): ~750 steps/s without images, ~58 steps/s with a 320x240 render per step. It cannot
be re-measured in the same run: Gymnasium-Robotics 1.4.2 crashes on mujoco >= 3.17.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ["LP_NUM_THREADS"] = "1"  # llvmpipe rasterizer threads: one core means one thread
os.environ.setdefault("OMP_NUM_THREADS", "1")

FETCH_REFERENCE = {"no_images": 750.0, "camera_320x240": 58.0}
TARGET_RATIO = 2.0


def measure(env, steps: int, seed: int) -> float:
    import numpy as np

    env.reset(seed=seed)
    env.action_space.seed(seed)
    actions = [env.action_space.sample() for _ in range(steps)]
    elapsed = 0.0
    for a in actions:
        t0 = time.perf_counter()
        _, _, terminated, truncated, _ = env.step(a)
        elapsed += time.perf_counter() - t0
        if terminated or truncated:
            env.reset()
    return steps / elapsed if elapsed > 0 else float(np.inf)


def plot(report: dict, path: Path) -> None:
    """Bar chart: measured steps/s against the FetchPickAndPlace reference and the 2x target."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pose.fileio import atomic_write

    names = list(report["results"])
    fig, axes = plt.subplots(1, len(names), figsize=(4 * len(names), 3.2))
    for ax, name in zip(axes, names, strict=True):
        r = report["results"][name]
        ref = r["fetch_pick_and_place_reference"]
        ax.bar(
            ["FetchPickAndPlace\n(reference)", "ScorbotGrasp-v0"],
            [ref, r["steps_per_second_median"]],
            color=["#999999", "#3a78b5"],
        )
        ax.axhline(TARGET_RATIO * ref, color="#c44", ls="--", label=f"target {TARGET_RATIO:g}x")
        ax.set_title(name.replace("_", " "))
        ax.set_ylabel("env steps / s (one core, median)")
        ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    atomic_write(path, lambda f: fig.savefig(f, dpi=100, format="png"))
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--cpu", type=int, default=0, help="core to pin to")
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/env_step.json"))
    args = parser.parse_args(argv)
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {args.cpu})

    import gymnasium as gym
    import numpy as np

    import scorbot_gym
    from pose.fileio import atomic_write_json

    settings = {
        "no_images": {},
        "camera_320x240": {"cameras": ["top"], "image_width": 320, "image_height": 240},
    }
    results = {}
    for name, kwargs in settings.items():
        env = gym.make("ScorbotGrasp-v0", object_name="tomato_soup_can", **kwargs)
        steps = args.steps if not kwargs else max(200, args.steps // 10)
        measure(env, min(steps, 100), seed=999)  # warm-up: GL context, caches
        runs = [measure(env, steps, seed=i) for i in range(args.repeats)]
        env.close()
        med = float(np.median(runs))
        results[name] = {
            "steps_per_second_median": med,
            "steps_per_second_runs": runs,
            "steps_per_run": steps,
            "fetch_pick_and_place_reference": FETCH_REFERENCE[name],
            "ratio_to_reference": med / FETCH_REFERENCE[name],
            "meets_target": med / FETCH_REFERENCE[name] >= TARGET_RATIO,
        }
        print(
            f"{name:>15}: {med:8.1f} steps/s (median of {args.repeats}), "
            f"{med / FETCH_REFERENCE[name]:.2f}x FetchPickAndPlace reference"
        )
    report = {
        "benchmark": "env_step",
        "env": "ScorbotGrasp-v0 (joint actions, tomato_soup_can, random actions)",
        "control_dt_s": 0.04,
        "physics_substeps_per_step": 20,
        "one_core": True,
        "target_ratio": TARGET_RATIO,
        "results": results,
        "machine": {
            "platform": platform.platform(),
            "python": sys.version.split()[0],
            "cpu_count": os.cpu_count(),
            "scorbot_gym": scorbot_gym.__version__,
        },
    }
    atomic_write_json(args.out, report)
    plot(report, args.out.with_suffix(".png"))
    print(f"written {args.out} and {args.out.with_suffix('.png')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
