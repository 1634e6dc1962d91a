"""Closed-loop grasping of a named target on a cluttered table (issue 37, item 2).

Every arm runs the same seeded episodes: the target drawn from the catalogue, ``--distractors``
other catalogue objects drawn beside it (seeded, close enough to touch and occlude), the
scripted controller re-planning from every estimate:

- ``oracle``: the target's true pose (the ceiling);
- ``manifold_clutter``: background subtraction split into blobs, every blob recognised (FLR
  shortlist + appearance), the target's pose estimated on its blob by the default top-camera
  pose models; no privileged input, the target named by the task command;
- ``manifold_largest_blob``: the single-object source as it is (the largest blob, the target's
  model): what the loop did before blobs were split, the baseline.

Writes ``benchmarks/results/clutter_closed_loop.json`` (``_quick`` with ``--quick``): per arm the
rollout summary (success with its 95 % interval, failure causes with ``wrong_object``,
distractors knocked over, perception: target recognition, blob recognition, errors, timings).

    python benchmarks/clutter_closed_loop.py [--episodes 40] [--distractors 2] [--jobs 2]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

ARMS = {
    "oracle": {"pose": "oracle"},
    "manifold_clutter": {"pose": "manifold_clutter"},
    "manifold_largest_blob": {"pose": "manifold"},
}


def run_arm(label: str, config, progress: bool) -> dict:
    from scorbot_gym.evaluation.rollout import run_rollout

    t0 = time.perf_counter()
    summary, _ = run_rollout(config, progress=progress)
    summary.pop("results", None)
    summary["label"] = label
    summary["wall_s"] = time.perf_counter() - t0
    p = summary.get("perception") or {}
    lo, hi = summary["success_rate_ci95"]
    print(
        f"{label:>22}: success {summary['success_rate']:6.1%} (95% CI {lo:.1%}-{hi:.1%}) "
        f"n={summary['episodes']}  target recog {p.get('target_recognition_accuracy')}  "
        f"failures {summary['failure_causes']}  knocked {summary.get('distractors_knocked_over')}",
        flush=True,
    )
    return summary


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=40)
    ap.add_argument("--distractors", type=int, default=2)
    ap.add_argument("--seed", type=int, default=5000, help="first episode's seed")
    ap.add_argument("--arms", nargs="+", choices=sorted(ARMS), default=list(ARMS))
    ap.add_argument("--quick", action="store_true", help="4 episodes, written to *_quick.json")
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--jobs", type=int, default=1, help="arms run in this many processes")
    ap.add_argument("--no-progress", action="store_true")
    args = ap.parse_args(argv)
    if args.episodes < 1 or args.distractors < 0 or args.jobs < 1:
        ap.error("--episodes and --jobs must be >= 1, --distractors >= 0")
    episodes = 4 if args.quick else args.episodes

    import cv2

    from pose.fileio import atomic_write_json
    from scorbot_gym.evaluation.rollout import RolloutConfig

    cv2.setNumThreads(1)
    configs = {
        label: RolloutConfig(
            episodes=episodes, seed=args.seed, distractors=args.distractors, **ARMS[label]
        )
        for label in args.arms
    }
    progress = not args.no_progress and args.jobs == 1
    if args.jobs > 1:  # spawned: no GL context is inherited
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(args.jobs, mp_context=mp.get_context("spawn")) as pool:
            futures = {k: pool.submit(run_arm, k, c, False) for k, c in configs.items()}
            arms = {k: f.result() for k, f in futures.items()}
    else:
        arms = {k: run_arm(k, c, progress) for k, c in configs.items()}
    name = "clutter_closed_loop_quick.json" if args.quick else "clutter_closed_loop.json"
    out = args.out or Path(__file__).parent / "results" / name
    atomic_write_json(
        out,
        {
            "episodes": episodes,
            "distractors": args.distractors,
            "seed": args.seed,
            "arms": arms,
            "machine": {"platform": platform.platform(), "cpus": os.cpu_count()},
        },
    )
    print(f"written {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
