"""``scorbot-gym demos``: record scripted demonstrations as a Minari dataset."""

from __future__ import annotations

import argparse

from scorbot_gym.cli._args import non_negative_float, non_negative_int, positive_int
from scorbot_gym.names import IDENTITIES


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "demos",
        help="record scripted demonstrations as a Minari dataset",
        description="Run seeded episodes of the scripted controller (which acts on the oracle "
        "pose: it is the demonstrator) and store observations (with the chosen pose source's "
        "estimates), actions, rewards, terminations, truncations and infos (the controller's "
        "clean action as infos['expert_action'], camera calibration, the estimator's record) "
        "as a Minari dataset under MINARI_DATASETS_PATH. `minari.load_dataset(NAME)` opens it; "
        "benchmarks/learned_policy.py --dataset NAME trains on it.",
    )
    p.add_argument("--episodes", type=positive_int, default=100)
    p.add_argument(
        "--pose",
        choices=("oracle", "manifold"),
        default="oracle",
        help="pose source whose estimates the observations carry (default: oracle)",
    )
    p.add_argument(
        "--identity",
        choices=IDENTITIES,
        default=None,
        help="--pose manifold only: recognize (default: the object is recognised from the top "
        "and side views, no privileged input) or given (privileged: the estimator is told the "
        "true class); recorded in the dataset's settings",
    )
    p.add_argument(
        "--out",
        required=True,
        metavar="NAME",
        help="Minari dataset id, e.g. scorbot/grasp-oracle-v0",
    )
    p.add_argument(
        "--seed",
        type=non_negative_int,
        default=None,
        help="seed of the first episode (default: the start of the demonstration seeds, "
        "scorbot_gym.seeds.DEMONSTRATIONS; a warning if they overlap an evaluation range)",
    )
    p.add_argument(
        "--dart-sigma",
        type=non_negative_float,
        default=0.0,
        help="std of Gaussian noise added to the executed arm action (DART); labels stay clean",
    )
    p.add_argument(
        "--action-type", choices=("joint", "cartesian"), default="cartesian", help="action space"
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from scorbot_gym.rl.datasets import record_demonstrations

    env_id = "ScorbotGraspCartesian-v0" if args.action_type == "cartesian" else "ScorbotGrasp-v0"

    def progress(done: int, total: int) -> None:
        print(f"\r{done}/{total} episodes", end="\n" if done == total else "", flush=True)

    ds = record_demonstrations(
        args.out,
        episodes=args.episodes,
        pose=args.pose,
        identity=args.identity,
        seed=args.seed,
        dart_sigma=args.dart_sigma,
        progress=progress,
        env_id=env_id,
    )
    print(f"dataset {args.out}: {ds.total_episodes} episodes, {ds.total_steps} steps")
    print(ds.storage.metadata.get("description", ""))
    return 0
