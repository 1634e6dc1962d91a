"""Learning curves over seeds: mean success and return with a 95 % band, against env steps and
training wall time, and the steps and time each seed took to reach 50 % and 80 % success.

Reads the evaluation logs of ``scorbot-gym train`` run folders (a ``--seeds`` folder counts as
its seeds) and writes JSON + PNG (:mod:`scorbot_gym.rl.curves`). With ``--train``, an arm whose
folder holds no run yet is first trained with ``scorbot-gym train --seeds`` settings from
``PRESETS`` (and one that stopped early, or was interrupted, is resumed: run the same command
again), ``--parallel`` seeds at a time in processes of their own, so the figure is
reproducible. Learning from scratch (#49) on a 16-core GPU machine, 1M env steps:

    python benchmarks/learning_curves.py --train --arm scratch=runs/scratch_sac_cartesian \\
        --algo sac --action-type cartesian --seeds 0,1,2 --parallel 3 --timesteps 1000000 \\
        --eval-every 10000 --eval-episodes 50 --checkpoint-every 50000 \\
        --out runs/scratch_sac_cartesian.json
    python benchmarks/learning_curves.py --arm residual=runs/curves_residual --train \\
        --seeds 0,1,2 --timesteps 3000
    python benchmarks/learning_curves.py --arm sac=runs/a --arm tqc=runs/b   # existing runs

By default the JSON and PNG go to a new ``runs/learning_curves-<time>/``; ``--out`` names the
file (an existing one only with ``--overwrite``), and ``--config NAME`` stores the run as the
variant ``configs[NAME]`` of it, without a figure, the file's other runs kept. The committed
record is updated by adding ``--out benchmarks/results/learning_curves.json --overwrite`` to
the command (and ``--config residual_no_burnin`` or ``scratch_56k`` for its variants; the main
run's command is in ``benchmarks/README.md``).
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
from pathlib import Path

from scorbot_gym.cli._args import add_ray, seed_list

os.environ.setdefault("MUJOCO_GL", "egl")

#: TrainConfig settings of the arms --train can start (oracle pose; --algo, --action-type)
PRESETS = {
    "residual": {"residual": True},
    # learning from scratch: the 'scratch' hyperparameters (SAC: normalized_pregrasp, gamma 0.8) ...
    "scratch": {"hyperparams_entry": "scratch"},
    # ... and the same with the old dense reward, the reward ablation
    "scratch_dense": {
        "hyperparams_entry": "scratch",
        "hyperparams": {"reward_type": "dense", "reward_gamma": 0.99},  # the one it is built for
    },
    # ... and trained on a pose hidden while the hand is near the object, as an image
    # estimator's is (OccludedOraclePoseSource): a policy that acts from a held estimate
    "scratch_occluded": {"hyperparams_entry": "scratch", "pose": "occluded", "noise_pos_m": 0.005},
    # the 'default' entry (64x64, 50k buffer, dense reward): what learning_curves_scratch_56k ran
    "default": {},
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


def _gpu_name() -> str | None:
    """The CUDA device the runs' ``device="auto"`` updates on here, if any."""
    import torch

    return torch.cuda.get_device_name(0) if torch.cuda.is_available() else None


def main(argv: list[str] | None = None) -> int:
    from scorbot_gym.experiments.outputs import Outputs, add_overwrite_option

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
    parser.add_argument(
        "--checkpoint-every", type=_positive, default=None, help="with --train (default: eval)"
    )
    parser.add_argument("--algo", choices=("sac", "tqc", "ppo"), default="sac", help="with --train")
    parser.add_argument(
        "--action-type", choices=("cartesian", "joint"), default="cartesian", help="with --train"
    )
    parser.add_argument(
        "--n-envs", type=_positive, default=1, help="with --train: vector envs per seed (PPO: 8-16)"
    )
    parser.add_argument(
        "--device", default="auto", help="with --train: auto (CUDA when there is one), cpu, cuda"
    )
    parser.add_argument(
        "--parallel",
        type=_positive,
        default=1,
        help="with --train: runs (seeds of every arm) trained at a time, each in its own process",
    )
    add_ray(
        parser,
        "with --train: every run a Ray task, on a local instance of --parallel CPUs or the "
        "cluster at ADDRESS (its workers need scorbot-gym and the run folders at the same paths)",
    )
    parser.add_argument(
        "--hyperparams",
        nargs="+",
        default=[],
        metavar="KEY=VALUE",
        help="with --train: overrides on top of each preset's entry, e.g. buffer_size=100000",
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        help="results JSON, the PNG beside it (default: runs/learning_curves-<time>/)",
    )
    add_overwrite_option(parser)
    parser.add_argument(
        "--config",
        default=None,
        help="store the run as this named variant of --out (default: the file's main run)",
    )
    args = parser.parse_args(argv)
    try:  # before any work: an existing file is not replaced unless asked
        args.out = Outputs("learning_curves", args.overwrite).path(
            args.out, "learning_curves.json", companions=[".png"] if args.config is None else []
        )
    except ValueError as exc:
        parser.error(str(exc))
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
    from scorbot_gym.rl.hyperparams import parse_overrides
    from scorbot_gym.rl.training import TrainConfig

    trained = {}
    if args.train:
        configs = {}
        for label in arms:
            preset = dict(PRESETS[label])
            try:
                overrides = parse_overrides(args.hyperparams)
                preset["hyperparams"] = {**preset.get("hyperparams", {}), **overrides}
                configs[label] = TrainConfig(
                    **preset,
                    algo=args.algo,
                    action_type=args.action_type,
                    n_envs=args.n_envs,
                    device=args.device,
                    timesteps=args.timesteps,
                    eval_every=args.eval_every,
                    eval_episodes=args.eval_episodes,
                    checkpoint_every=args.checkpoint_every or args.eval_every,
                    progress_bar=False,
                ).validate()
            except ValueError as exc:
                parser.error(f"arm {label}: {exc}")
        # every arm's seeds in one pool of --parallel processes: the arms of a comparison
        # share the machine's load, so their wall times compare
        from scorbot_gym.rl import runs
        from scorbot_gym.rl.training import run_seed_jobs, seed_jobs, start_seeds

        jobs = {}
        for label, (folder,) in arms.items():
            if (folder / runs.SEEDS).is_file():  # interrupted or shorter: continued
                print(f"arm {label}: resuming {folder} (its seeds.json and checkpoints)")
            else:
                start_seeds(configs[label], folder, args.seeds)
            jobs.update(seed_jobs(folder, timesteps=args.timesteps, device=args.device))
        run_seed_jobs(jobs, processes=args.parallel, ray=args.ray)
        for label in arms:
            trained[label] = {
                "preset": PRESETS[label],
                "hyperparams_overrides": parse_overrides(args.hyperparams),
                "algo": args.algo,
                "action_type": args.action_type,
                "n_envs": args.n_envs,
                "seeds": args.seeds,
                "parallel": args.parallel,
                "ray": args.ray,
            }

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
            "gpu": _gpu_name(),
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
        for level, hit in arm["first_reached"].items():
            print(
                f"  {float(level):.0%} reached by {hit['seeds_reached']} seeds: {hit['timesteps']}"
            )
    figure = f" and {args.out.with_suffix('.png')}" if args.config is None else ""
    print(f"written {args.out}{figure}" + (f" (config {args.config!r})" if args.config else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
