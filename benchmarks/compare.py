"""The scripted-vs-learned comparison table: paired seeds, Wilson CIs, paired-difference CIs.

Runs :func:`scorbot_gym.evaluation.compare.compare` for the scripted controller (reference),
the shipped residual policy (``rl``) under the oracle pose and noisy-oracle levels on the whole
catalogue; further policy directories (``--extra``, e.g. the behaviour-cloned and from-scratch
arms of ``benchmarks/rl_training.py``) against the scripted controller under the oracle pose on
the first ``--extra-episodes`` of the same seeds; optionally scripted vs ``rl`` with the
pose-manifold estimator (``--pose-model``; fewer episodes, as rendering and estimating every
step is slow). Writes ``benchmarks/results/compare.json`` and ``.png`` (per-object success,
success vs noise).

    python benchmarks/compare.py [--episodes 200] [--noise 0.005,0.01,0.02] \
        [--extra runs/bc_sac_oracle/policy runs/scratch_sac_oracle/policy --extra-episodes 50] \
        [--pose-model pose_models.npz --manifold-episodes 40]
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
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--noise", default="0.005,0.01,0.02", help="position std levels (m)")
    parser.add_argument("--extra", nargs="*", default=[], help="more policy directories")
    parser.add_argument("--extra-episodes", type=int, default=50)
    parser.add_argument("--pose-model", type=Path, default=None)
    parser.add_argument("--manifold-episodes", type=int, default=40)
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/compare.json"))
    args = parser.parse_args(argv)

    import torch

    import scorbot_gym
    from pose.fileio import atomic_write_json
    from scorbot_gym.cli.compare import format_report
    from scorbot_gym.evaluation.compare import compare, plot_comparison

    torch.set_num_threads(1)  # one-sample predictions: threads only add contention
    policies = ["scripted", "rl"]
    noise = [float(v) for v in args.noise.split(",") if v]
    t0 = time.perf_counter()
    report = compare(policies, ["oracle"], args.episodes, args.seed, noise=noise, progress=False)
    report["wall_s"] = {"oracle_and_noise": time.perf_counter() - t0}
    if args.extra:
        t0 = time.perf_counter()
        extra = compare(
            ["scripted", *args.extra], ["oracle"], args.extra_episodes, args.seed, progress=False
        )
        report["wall_s"]["extra"] = time.perf_counter() - t0
        report["extra"] = {"episodes": args.extra_episodes, "results": extra["results"]}
        report["differences"] += extra["differences"]
    if args.pose_model is not None:
        t0 = time.perf_counter()
        mani = compare(
            policies, ["manifold"], args.manifold_episodes, args.seed,
            pose_model=args.pose_model, progress=False,
        )  # fmt: skip
        report["wall_s"]["manifold"] = time.perf_counter() - t0
        report["manifold"] = {
            "episodes": args.manifold_episodes,
            "pose_model": str(args.pose_model),
        }
        report["results"] += mani["results"]
        report["differences"] += mani["differences"]
    report["machine"] = {
        "platform": platform.platform(),
        "cpu_count": os.cpu_count(),
        "scorbot_gym": scorbot_gym.__version__,
    }
    atomic_write_json(args.out, report)
    plot_comparison(report, args.out.with_suffix(".png"))
    print(format_report(report))
    print(f"written {args.out} and {args.out.with_suffix('.png')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
