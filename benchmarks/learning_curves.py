"""Learning curves over seeds: mean success with a 95 % band, against env steps and wall time.

Reads the evaluation logs of ``scorbot-gym train`` run folders (a ``--seeds`` folder counts as
its seeds) and writes JSON + PNG (:mod:`scorbot_gym.rl.curves`). With ``--train``, an arm whose
folder holds no run yet is first trained with ``scorbot-gym train --seeds`` settings from
``PRESETS`` (and one that stopped early is resumed), so the figure is reproducible:

    python benchmarks/learning_curves.py --arm residual=runs/curves_residual --train \\
        --seeds 0,1,2 --timesteps 3000
    python benchmarks/learning_curves.py --arm sac=runs/a --arm tqc=runs/b   # existing runs
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
from pathlib import Path

from scorbot_gym.cli._args import seed_list

os.environ.setdefault("MUJOCO_GL", "egl")

#: TrainConfig settings of the arms --train can start (oracle pose, Cartesian actions)
PRESETS = {
    "residual": {"residual": True},
    "scratch": {},
    "bc": {"bc_demos": 100, "bc_steps": 3000},
}


def _arm(text: str) -> tuple[str, list[Path]]:
    label, sep, dirs = text.partition("=")
    if not sep or not label or not dirs:
        raise argparse.ArgumentTypeError(f"must be LABEL=DIR[,DIR...], got {text!r}")
    return label, [Path(d) for d in dirs.split(",") if d]


def _positive(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be an integer >= 1, got {text}")
    return value


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--arm", type=_arm, action="append", required=True, help="LABEL=DIR[,DIR...]"
    )
    parser.add_argument(
        "--train",
        action="store_true",
        help=f"train arms whose label is a preset ({', '.join(PRESETS)}) and whose folder "
        "holds no run yet (or resume them)",
    )
    parser.add_argument("--seeds", type=seed_list, default=[0, 1, 2], help="with --train")
    parser.add_argument("--timesteps", type=_positive, default=3000, help="with --train")
    parser.add_argument("--eval-every", type=_positive, default=1000, help="with --train")
    parser.add_argument("--eval-episodes", type=_positive, default=10, help="with --train")
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/learning_curves.json"))
    parser.add_argument(
        "--config",
        default=None,
        help="store the run as this named variant of --out (default: the file's main run)",
    )
    args = parser.parse_args(argv)
    arms = dict(args.arm)
    if args.train:
        unknown = sorted(set(arms) - set(PRESETS))
        if unknown:
            parser.error(f"--train: arms {unknown} are not presets ({', '.join(PRESETS)})")
        if any(len(d) != 1 for d in arms.values()):
            parser.error("--train: give one folder per arm (its seeds go into seed_<S>/)")
    else:
        missing = [str(d) for dirs in arms.values() for d in dirs if not d.is_dir()]
        if missing:
            parser.error(f"no run folder at {', '.join(missing)} (--train trains preset arms)")

    import scorbot_gym
    from pose.fileio import write_result
    from scorbot_gym.rl.curves import learning_curves, plot_learning_curves

    trained = {}
    if args.train:
        from scorbot_gym.rl import runs
        from scorbot_gym.rl.training import TrainConfig, resume, train_seeds

        for label, (folder,) in arms.items():
            config = TrainConfig(
                **PRESETS[label],
                timesteps=args.timesteps,
                eval_every=args.eval_every,
                eval_episodes=args.eval_episodes,
                checkpoint_every=args.eval_every,
                progress_bar=False,
            )
            if (folder / runs.SEEDS).is_file():
                resume(folder, timesteps=args.timesteps)
            else:
                train_seeds(config, folder, args.seeds)
            trained[label] = {"preset": PRESETS[label], "seeds": args.seeds}

    try:
        curves = learning_curves(arms)
    except (ValueError, FileNotFoundError) as exc:
        parser.error(str(exc))
    report = {
        "benchmark": "learning_curves",
        "what": "success rate on held-out seeds (each run's own evaluations); mean over seeds "
        "and the Student-t 95 % interval of the mean, against env steps and training wall "
        "time (evaluation excluded)",
        "trained_here": trained,
        "arms": curves,
        "machine": {
            "platform": platform.platform(),
            "cpu_count": os.cpu_count(),
            "load_avg_1m_at_end": os.getloadavg()[0],
            "scorbot_gym": scorbot_gym.__version__,
        },
    }
    write_result(args.out, report, args.config)
    if args.config is None:  # the figure is the main run's
        plot_learning_curves(report["arms"], args.out.with_suffix(".png"))
    for label, arm in report["arms"].items():
        final = arm["by_timesteps"]
        lo, hi = final["ci95_low"], final["ci95_high"]
        band = f" (95% CI {lo[-1]:.1%} - {hi[-1]:.1%})" if lo else ""
        steps = int(final["timesteps"][-1])
        print(f"{label}: {final['mean'][-1]:.1%}{band} at {steps} env steps, seeds {arm['seeds']}")
    figure = f" and {args.out.with_suffix('.png')}" if args.config is None else ""
    print(f"written {args.out}{figure}" + (f" (config {args.config!r})" if args.config else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
