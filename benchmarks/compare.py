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
        [--pose-model pose_models.npz --manifold-episodes 40] [--jobs 2]
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
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--noise", default="0.005,0.01,0.02", help="position std levels (m)")
    parser.add_argument("--extra", nargs="*", default=[], help="more policy directories")
    parser.add_argument("--extra-episodes", type=int, default=50)
    parser.add_argument("--pose-model", type=Path, default=None)
    parser.add_argument("--manifold-episodes", type=int, default=40)
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/compare.json"))
    parser.add_argument("--jobs", type=int, default=1, help="run the parts in this many processes")
    args = parser.parse_args(argv)

    import scorbot_gym
    from pose.fileio import atomic_write_json
    from scorbot_gym.cli.compare import format_report
    from scorbot_gym.evaluation.compare import plot_comparison

    noise = [float(v) for v in args.noise.split(",") if v]
    parts = {"oracle_and_noise": (["scripted", "rl"], ["oracle"], args.episodes, noise, None)}
    if args.extra:
        parts["extra"] = (["scripted", *args.extra], ["oracle"], args.extra_episodes, [], None)
    if args.pose_model is not None:
        parts["manifold"] = (
            ["scripted", "rl"], ["manifold"], args.manifold_episodes, [], args.pose_model
        )  # fmt: skip
    if args.jobs > 1:  # spawned: a forked child of a process that has rendered cannot render
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(args.jobs, mp_context=mp.get_context("spawn")) as pool:
            futures = {k: pool.submit(_part, *v, args.seed) for k, v in parts.items()}
            done = {k: f.result() for k, f in futures.items()}
    else:
        done = {k: _part(*v, args.seed) for k, v in parts.items()}
    report, wall = done["oracle_and_noise"]
    report["wall_s"] = {"oracle_and_noise": wall}
    if "extra" in done:
        extra, report["wall_s"]["extra"] = done["extra"]
        report["extra"] = {"episodes": args.extra_episodes, "results": extra["results"]}
        report["differences"] += extra["differences"]
    if "manifold" in done:
        mani, report["wall_s"]["manifold"] = done["manifold"]
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


def _part(policies, poses, episodes, noise, pose_model, seed) -> tuple[dict, float]:
    """One :func:`compare` call and its wall time (a separate process under ``--jobs``)."""
    import torch

    from scorbot_gym.evaluation.compare import compare

    torch.set_num_threads(1)  # one-sample predictions: threads only add contention
    t0 = time.perf_counter()
    report = compare(
        policies, poses, episodes, seed, noise=noise, pose_model=pose_model, progress=False
    )
    return report, time.perf_counter() - t0


if __name__ == "__main__":
    sys.exit(main())
