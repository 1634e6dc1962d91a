"""Grasp success with the estimated pose against the ground-truth pose, over the catalogue.

Trains pose-manifold models (or loads ``--model``), then runs the scripted controller for
``--per-object`` seeded episodes of every catalogue object, once grasping at the true pose and
once at the pose the estimator reads from the top camera, and writes
``benchmarks/results/closed_loop.json``.

    python benchmarks/closed_loop.py [--per-object 5] [--model pose_models.npz]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--per-object", type=int, default=5)
    parser.add_argument("--model", type=Path, default=None, help="skip training, load this file")
    parser.add_argument("--seed", type=int, default=100)
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/closed_loop.json"))
    args = parser.parse_args(argv)

    import scorbot_gym
    from pose.fileio import atomic_write_json
    from pose.model_set import PoseModelSet
    from scorbot_gym.envs.factory import make_env
    from scorbot_gym.evaluation import run_episode, summarize
    from scorbot_gym.objects import CATALOGUE
    from scorbot_gym.perception.training import train_models
    from scorbot_gym.policies import ScriptedGraspPolicy

    t0 = time.perf_counter()
    if args.model is None:
        models, _ = train_models(width=640, height=480, jobs=2, progress=False)
    else:
        models = PoseModelSet.load(args.model)
    train_s = time.perf_counter() - t0
    sources = {"oracle": {}, "manifold": {"models": models}}
    report: dict = {"benchmark": "closed_loop", "per_object": args.per_object, "results": {}}
    for label, pose_kwargs in sources.items():
        env = make_env(pose=label, pose_kwargs=pose_kwargs, estimate_every=0)
        policy = ScriptedGraspPolicy.for_env(env)
        results = [
            run_episode(env, policy, args.seed + i, options={"object_name": name})
            for name in CATALOGUE
            for i in range(args.per_object)
        ]
        env.close()
        summary = summarize(results)
        report["results"][label] = summary
        lo, hi = summary["success_rate_ci95"]
        print(
            f"{label:>9}: success {summary['success_rate']:.1%} (95% CI {lo:.1%}-{hi:.1%}) "
            f"over {summary['episodes']} episodes; perception {summary['perception']}"
        )
    report["train_s"] = None if args.model else train_s
    report["machine"] = {
        "platform": platform.platform(),
        "cpu_count": os.cpu_count(),
        "scorbot_gym": scorbot_gym.__version__,
    }
    atomic_write_json(args.out, report)
    print(f"written {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
