"""``scorbot-gym train``: train an SB3 agent on the grasping env, or resume a run."""

from __future__ import annotations

import argparse
from pathlib import Path

from scorbot_gym.cli._args import add_name_list
from scorbot_gym.objects import CATALOGUE
from scorbot_gym.rl.training import ALGOS, POSES, TrainConfig, resume, train


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "train",
        help="train a learned grasping policy (SB3 SAC/TQC/PPO), or resume a run",
        description="Train into --out (config, checkpoints, TensorBoard logs, exported policy/),"
        " or continue an interrupted run with --resume DIR.",
    )
    p.add_argument("--algo", choices=ALGOS, default="sac")
    p.add_argument("--pose", choices=POSES, default="oracle", help="pose source in training")
    p.add_argument("--pose-model", type=Path, default=None, help="with --pose manifold")
    p.add_argument("--action-type", choices=("cartesian", "joint"), default="cartesian")
    add_name_list(p, "--objects", CATALOGUE, "training objects (default: all)")
    p.add_argument(
        "--timesteps",
        type=int,
        default=None,
        help="total env steps (default 20000; with --resume: a new total to continue to)",
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--n-envs", type=int, default=1, help="SubprocVecEnv workers (1: in-process)")
    p.add_argument("--out", type=Path, default=None, help="run directory (new)")
    p.add_argument("--resume", type=Path, default=None, help="continue the run in this directory")
    p.add_argument(
        "--residual", action="store_true", help="learn a residual on top of the scripted controller"
    )
    p.add_argument("--residual-scale", type=float, default=0.3)
    p.add_argument(
        "--bc-demos",
        type=int,
        default=0,
        help="scripted demonstration episodes: replay buffer + behaviour cloning",
    )
    p.add_argument("--bc-steps", type=int, default=2000, help="behaviour-cloning gradient steps")
    p.add_argument("--net-arch", type=int, nargs="+", default=[64, 64])
    p.add_argument("--learning-starts", type=int, default=1000)
    p.add_argument("--eval-every", type=int, default=5000, help="env steps between evaluations")
    p.add_argument("--eval-episodes", type=int, default=20)
    p.add_argument("--checkpoint-every", type=int, default=5000)
    p.add_argument("--no-tensorboard", action="store_true")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if (args.out is None) == (args.resume is None):
        raise ValueError("give exactly one of --out DIR (a new run) or --resume DIR")
    if args.resume is not None:
        state = resume(args.resume, timesteps=args.timesteps)
        out = args.resume
    else:
        config = TrainConfig(
            algo=args.algo,
            pose=args.pose,
            pose_model=str(args.pose_model) if args.pose_model else None,
            action_type=args.action_type,
            objects=args.objects,
            timesteps=20_000 if args.timesteps is None else args.timesteps,
            seed=args.seed,
            n_envs=args.n_envs,
            residual=args.residual,
            residual_scale=args.residual_scale,
            bc_demos=args.bc_demos,
            bc_steps=args.bc_steps,
            net_arch=args.net_arch,
            learning_starts=args.learning_starts,
            eval_every=args.eval_every,
            eval_episodes=args.eval_episodes,
            checkpoint_every=args.checkpoint_every,
            progress_bar=not args.no_progress,
            tensorboard=not args.no_tensorboard,
        )
        state = train(config, args.out)
        out = args.out
    last = state["eval"][-1]
    lo, hi = last["ci95"]
    print(
        f"{state['timesteps']} env steps in {state['wall_s']:.0f} s of training; success on "
        f"{last['episodes']} held-out episodes: {last['success_rate']:.1%} "
        f"(95% CI {lo:.1%} - {hi:.1%})"
    )
    print(f"policy: {out / 'policy'}  (scorbot-gym compare --policies scripted,{out / 'policy'})")
    return 0
