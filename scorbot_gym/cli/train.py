"""``scorbot-gym train``: train an SB3 agent on the grasping env (one or several seeds), or
resume a run. Every option is checked while parsing; SB3 and torch are imported only to train.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from scorbot_gym.cli._args import (
    add_name_list,
    add_ray,
    non_negative_float,
    non_negative_int,
    positive_int,
    seed_list,
)
from scorbot_gym.names import IDENTITIES
from scorbot_gym.objects import CATALOGUE
from scorbot_gym.rl import hyperparams as hparams

#: options that define a new run: with --resume the run's own settings apply (only --timesteps)
_NEW_RUN_OPTIONS = (
    "algo",
    "pose",
    "pose_model",
    "identity",
    "pos_sigma_m",
    "yaw_sigma_deg",
    "hide_distance_m",
    "residual_gripper",
    "action_type",
    "objects",
    "seed",
    "seeds",
    "n_envs",
    "residual",
    "residual_scale",
    "bc_demos",
    "bc_steps",
    "init_policy",
    "init_weights",
    "hyperparams_entry",
    "conf",
    "hyperparams",
    "net_arch",
    "learning_starts",
    "eval_every",
    "eval_episodes",
    "checkpoint_every",
)


def _positive_float(text: str) -> float:
    value = float(text)
    if not (0 < value < float("inf")):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text}")
    return value


def _run_folder(text: str) -> Path:
    path = Path(text)
    if not text or not path.is_dir():
        raise argparse.ArgumentTypeError(f"no run folder at {text}")
    return path


def _existing_file(text: str) -> Path:
    path = Path(text)
    if not path.is_file():
        raise argparse.ArgumentTypeError(f"no such file: {text}")
    return path


class _Overrides(argparse.Action):
    """``--hyperparams k=v [k=v ...]``: values read as YAML; names checked once the algorithm
    is known (after parsing)."""

    def __call__(self, parser, namespace, values, option_string=None):
        try:
            setattr(namespace, self.dest, hparams.parse_overrides(values))
        except ValueError as exc:
            parser.error(f"{option_string}: {exc}")


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "train",
        help="train a learned grasping policy (SB3 SAC/TQC/PPO), or resume a run",
        description="Train into --out (config.json, hyperparams.yml, Monitor CSVs, checkpoints, "
        "TensorBoard logs, the last policy/ and the best/), or continue an interrupted run "
        "with --resume DIR. Hyperparameters come from the package's hyperparams/<algo>.yml "
        "(entry 'residual' or 'default'), overridden by your --conf FILE.yml, then by "
        "--hyperparams.",
    )
    p.add_argument("--algo", choices=hparams.ALGOS, default="sac")
    p.add_argument(
        "--pose",
        choices=hparams.POSES,
        default="oracle",
        help="pose source (occluded: the noisy oracle lost while the hand is near the object, "
        "as an image estimator's is: for policies that will act from a held estimate)",
    )
    p.add_argument(
        "--pose-model",
        type=_existing_file,
        default=None,
        help="model file, with --pose manifold (default: the top camera's default models, "
        "trained on first use and cached)",
    )
    p.add_argument(
        "--identity",
        choices=IDENTITIES,
        default=None,
        help="--pose manifold only: recognize (default: the object is recognised from the top "
        "and side views, no privileged input, as `rollout --pose manifold`) or given "
        "(privileged: the estimator is told the true class, for ablations; recorded in "
        "config.json and policy.json)",
    )
    p.add_argument(
        "--pos-sigma-m",
        type=non_negative_float,
        default=None,
        help="--pose noisy or occluded: x-y position noise of every estimate, m (default 0.01)",
    )
    p.add_argument(
        "--yaw-sigma-deg",
        type=non_negative_float,
        default=None,
        help="--pose noisy or occluded: heading noise of every estimate, deg (default 5)",
    )
    p.add_argument(
        "--hide-distance-m",
        type=non_negative_float,
        nargs=2,
        metavar=("LOW", "HIGH"),
        default=None,
        help="--pose occluded: the object is hidden while the hand is within a distance drawn "
        "per episode from [LOW, HIGH] m of it (default 0.06 0.2)",
    )
    p.add_argument("--action-type", choices=("cartesian", "joint"), default="cartesian")
    add_name_list(p, "--objects", CATALOGUE, "training objects (default: all)")
    p.add_argument(
        "--timesteps",
        type=positive_int,
        default=None,
        help="total env steps (default 20000; with --resume: a new total to continue to)",
    )
    seeds = p.add_mutually_exclusive_group()
    seeds.add_argument("--seed", type=non_negative_int, default=0)
    seeds.add_argument(
        "--seeds",
        type=seed_list,
        default=None,
        metavar="S,S,...",
        help="train one run per seed, one after another, into --out/seed_<S>/",
    )
    p.add_argument(
        "--n-envs", type=positive_int, default=1, help="SubprocVecEnv workers (1: in-process)"
    )
    p.add_argument(
        "--parallel",
        type=positive_int,
        default=1,
        metavar="N",
        help="with --seeds (or --resume of a --seeds folder): train N seeds at a time, each in "
        "a process of its own (default 1: one after another); with --ray local, its CPUs",
    )
    add_ray(
        p,
        "with --seeds (or --resume of a --seeds folder): each seed a Ray task, on a local "
        "instance or the cluster at ADDRESS (auto, ray://host:port; its workers need "
        "scorbot-gym and the run folder at the same path)",
    )
    p.add_argument(
        "--out",
        default=None,
        help="run folder: new or empty (or a run of this command that stopped before its first "
        "checkpoint); locked while training",
    )
    p.add_argument(
        "--resume", type=_run_folder, default=None, help="continue the run in this folder"
    )
    p.add_argument(
        "--residual", action="store_true", help="learn a residual on top of the scripted controller"
    )
    p.add_argument("--residual-scale", type=_positive_float, default=0.3)
    p.add_argument(
        "--residual-gripper",
        action="store_true",
        help="the residual corrects the gripper command too (default: the arm only)",
    )
    p.add_argument(
        "--bc-demos",
        type=non_negative_int,
        default=0,
        help="scripted demonstration episodes: replay buffer + behaviour cloning (with "
        "--init-policy: a demonstration buffer sampled in every batch)",
    )
    p.add_argument(
        "--init-policy",
        default=None,
        metavar="learned|DIR",
        help="fine-tune this imitation policy with SAC, RLPD-style (hyperparams sac.yml "
        "'finetune'; the saved policies are imitation-format folders)",
    )
    p.add_argument(
        "--init-weights",
        default=None,
        metavar="rl_scratch|DIR",
        help="start from this RL policy's networks and observation statistics (same algorithm, "
        "action type and network; a new replay buffer), e.g. to go on training it under "
        "--pose occluded",
    )
    p.add_argument(
        "--bc-steps", type=non_negative_int, default=2000, help="behaviour-cloning gradient steps"
    )
    p.add_argument(
        "--conf",
        type=_existing_file,
        default=None,
        metavar="FILE.yml",
        help="your hyperparameter file, in the schema of the package's hyperparams/<algo>.yml "
        "(an entry per setting: default, residual, finetune); the run's entry replaces the "
        "package's values it names, --hyperparams overrides it; copied into the run folder",
    )
    p.add_argument(
        "--hyperparams",
        nargs="+",
        action=_Overrides,
        default={},
        metavar="KEY=VALUE",
        help="override the YAML entry, e.g. gamma=0.98 net_arch=[256,256] ent_coef=auto_0.1 "
        f"(SAC/TQC: {', '.join(hparams.valid_keys('tqc'))}; "
        f"PPO: {', '.join(hparams.valid_keys('ppo'))})",
    )
    p.add_argument(
        "--hyperparams-entry",
        default=None,
        metavar="NAME",
        help="the entry of hyperparams/<algo>.yml, e.g. 'scratch' (learning from scratch with "
        "the normalized_dense reward); default: 'residual' with --residual, 'finetune' with "
        "--init-policy, else 'default'",
    )
    p.add_argument(
        "--device",
        default=None,
        help="where the networks update: auto (CUDA when there is one; the default), cpu, "
        "cuda, cuda:N (with --resume: move the run there)",
    )
    p.add_argument(
        "--net-arch",
        type=positive_int,
        nargs="+",
        default=None,
        help="hidden layer widths (same as --hyperparams net_arch=[...])",
    )
    p.add_argument(
        "--learning-starts",
        type=non_negative_int,
        default=None,
        help="random steps before updates (same as --hyperparams learning_starts=N)",
    )
    p.add_argument(
        "--eval-every", type=positive_int, default=5000, help="env steps between evaluations"
    )
    p.add_argument("--eval-episodes", type=positive_int, default=20)
    p.add_argument(
        "--checkpoint-every", type=positive_int, default=5000, help="env steps between checkpoints"
    )
    p.add_argument(
        "--show-hyperparams",
        action="store_true",
        help="print the resolved hyperparameters and SB3 schedule, then exit without training",
    )
    p.add_argument("--no-tensorboard", action="store_true")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=run, _parser=p)


def _overrides(args: argparse.Namespace) -> dict:
    overrides = dict(args.hyperparams)
    for key, value in (("net_arch", args.net_arch), ("learning_starts", args.learning_starts)):
        if value is None:
            continue
        if key in overrides:
            raise ValueError(f"--{key.replace('_', '-')} and --hyperparams {key}=... both given")
        overrides[key] = value
    return overrides


def config_from_args(args: argparse.Namespace):
    """The run's :class:`~scorbot_gym.rl.training.TrainConfig`, checked (hyperparameters too)."""
    from scorbot_gym.rl.training import TrainConfig

    noisy = args.pos_sigma_m is not None or args.yaw_sigma_deg is not None
    if args.pose not in ("noisy", "occluded") and noisy:
        raise ValueError("--pos-sigma-m and --yaw-sigma-deg apply only to --pose noisy or occluded")
    if args.pose != "occluded" and args.hide_distance_m is not None:
        raise ValueError("--hide-distance-m applies only to --pose occluded")
    low, high = args.hide_distance_m or (None, None)
    noise = {
        "noise_pos_m": args.pos_sigma_m,
        "noise_yaw_deg": args.yaw_sigma_deg,
        "hide_low_m": low,
        "hide_high_m": high,
    }
    overrides = _overrides(args)
    if args.conf is not None:
        setting = hparams.setting_for(args.residual, args.init_policy is not None)
        overrides = {**hparams.load_user_file(args.conf, args.algo, setting), **overrides}
    return TrainConfig(
        **{k: v for k, v in noise.items() if v is not None},
        algo=args.algo,
        pose=args.pose,
        pose_model=str(args.pose_model) if args.pose_model else None,
        identity=args.identity,
        action_type=args.action_type,
        objects=args.objects,
        timesteps=20_000 if args.timesteps is None else args.timesteps,
        seed=args.seed,
        n_envs=args.n_envs,
        residual=args.residual,
        residual_scale=args.residual_scale,
        residual_gripper=args.residual_gripper,
        bc_demos=args.bc_demos,
        bc_steps=args.bc_steps,
        init_policy=args.init_policy,
        init_weights=args.init_weights,
        hyperparams_entry=args.hyperparams_entry,
        device=args.device or "auto",
        normalize=args.init_policy is None,  # a fine-tune uses the policy's own statistics
        hyperparams=overrides,
        eval_every=args.eval_every,
        eval_episodes=args.eval_episodes,
        checkpoint_every=args.checkpoint_every,
        progress_bar=not args.no_progress,
        tensorboard=not args.no_tensorboard,
    ).validate()


def _summary(state: dict) -> str:
    last = state["eval"][-1]
    lo, hi = last["ci95"]
    return (
        f"{state['timesteps']} env steps in {state['wall_s']:.0f} s of training; success on "
        f"{last['episodes']} held-out episodes: {last['success_rate']:.1%} "
        f"(95% CI {lo:.1%} - {hi:.1%})"
    )


def run(args: argparse.Namespace) -> int:
    if args.show_hyperparams:
        import yaml

        config = config_from_args(args).resolved()
        record = {"hyperparams": config.hyperparams, "sb3": config.schedule()}
        print(yaml.safe_dump(record, sort_keys=False), end="")
        return 0
    if (args.out is None) == (args.resume is None):
        raise ValueError("give exactly one of --out DIR (a new run) or --resume DIR")
    if args.resume is not None:
        defaults = args._parser.parse_args([])
        given = [k for k in _NEW_RUN_OPTIONS if getattr(args, k) != getattr(defaults, k)]
        if given:
            flags = ", ".join(f"--{k.replace('_', '-')}" for k in given)
            raise ValueError(f"--resume continues the run's own settings; {flags} cannot change")
    if args.out is not None:  # before any work: a folder of something else is never touched
        from scorbot_gym.rl.runs import check_new_run_folder

        args.out = check_new_run_folder(args.out)
    from scorbot_gym.rl.training import resume, train, train_seeds

    if args.resume is not None:
        out = args.resume
        state = resume(
            out,
            timesteps=args.timesteps,
            progress_bar=False if args.no_progress else None,
            device=args.device,
            processes=args.parallel,
            ray=args.ray,
        )
    else:
        out, config = args.out, config_from_args(args)
        if args.parallel > 1 and not args.seeds:
            raise ValueError("--parallel runs several seeds: give --seeds S,S,...")
        if args.ray is not None and not args.seeds:
            raise ValueError("--ray runs the seeds as Ray tasks: give --seeds S,S,...")
        conf = args.conf
        if args.seeds:
            state = train_seeds(
                config,
                out,
                args.seeds,
                processes=args.parallel,
                hyperparams_file=conf,
                ray=args.ray,
            )
        else:
            state = train(config, out, hyperparams_file=conf)
    if "seeds" in state:  # a multi-seed folder
        for seed, seed_state in state["seeds"].items():
            print(f"seed {seed}: {_summary(seed_state)}")
        first = out / f"seed_{next(iter(state['seeds']))}"
        print(f"runs: {out}/seed_*  (scorbot-gym rollout --policy {first})")
        return 0
    print(_summary(state))
    print(f"policies: {out / 'policy'} (last), {out / 'best'} (best evaluation)")
    print(f"replay: scorbot-gym rollout --policy {out} [--checkpoint last] [--video run.mp4]")
    return 0
