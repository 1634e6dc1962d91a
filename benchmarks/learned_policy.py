"""Train the stand-alone learned policy (BC with DART + DAgger, oracle pose) and measure it
against the scripted controller on the same seeded episodes over the whole catalogue.

The learned policy uses no scripted controller at test time (``policy.json`` says
``"uses_scripted_controller": false``); the scripted controller labels its training states.
Records the training cost (wall time, demonstrations, env steps) next to the success rates.

    nice -n 5 python benchmarks/learned_policy.py [--demos 200] [--dagger-rounds 8]
        [--dagger-episodes 80] [--episodes 110] [--out DIR] [--json FILE] [--overwrite]
        [--dataset NAME]   # start from a Minari dataset from `scorbot-gym demos`
        [--poses oracle,noisy@0:20,noisy@0.02:0,manifold]   # what the learner observes
        [--init-policy learned]   # fine-tune the shipped policy instead of starting afresh
        [--pose-window 8]   # the policy remembers its last 8 fresh estimates
        [--pose-dispersion]   # ... and sees how much they disagree (HistorySpec)
        [--stall-steps 50]   # ... and how long its TCP has been still
        [--expert-keeps-close]  # DAgger labels "close" until the learner closes
        [--object-features grasp_frame]  # told the object's grasp frame, not its class
        [--objects catalogue,heldout:training]  # train on more shapes (evaluated on the catalogue)

``--poses`` (``ImitationConfig.poses``): the pose conditions the learner's observations come
from, round-robin over episodes, while the scripted controller labels from the oracle pose:
the policy learns to act on estimates (default: ``oracle``).

Writes the policy folder (``--out``) and ``learned_policy.json`` (``--json``), by default both
into a new ``runs/learned_policy-<UTC time>/``; a path named that exists is refused unless
``--overwrite`` is given (the shipped ``imitation_dagger_estimates`` was trained with
``--poses oracle,manifold --pose-window 8 --dagger-rounds 4 --stall-steps 50
--expert-keeps-close``; to replace it: ``--out scorbot_gym/policies/data/imitation_dagger_estimates
--json benchmarks/results/learned_policy.json --overwrite``). ``--dataset NAME`` trains on a
Minari dataset's demonstrations (its action type must be the env's, cartesian; the policy
records the dataset's settings). ``--config NAME`` stores the results as the variant
``configs[NAME]`` of ``--json`` (e.g. another ``--poses``), the file's other runs kept.
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")


def _evaluate(label: str, policy: str, episodes: int, seed: int, objects: tuple[str, ...]) -> dict:
    from scorbot_gym.evaluation.rollout import RolloutConfig, run_rollout

    t0 = time.perf_counter()
    config = RolloutConfig(
        policy=policy,
        pose="oracle",
        action_type="cartesian",
        episodes=episodes,
        seed=seed,
        objects=objects,
    )
    summary, _ = run_rollout(config, progress=False)
    summary.pop("results", None)
    summary.pop("perception", None)
    summary["wall_s"] = time.perf_counter() - t0
    lo, hi = summary["success_rate_ci95"]
    print(
        f"{label:>10}: success {summary['success_rate']:.1%} (95% CI {lo:.1%}-{hi:.1%}) "
        f"n={summary['episodes']} failures {summary['failure_causes']}",
        flush=True,
    )
    return summary


def main(argv: list[str] | None = None) -> None:
    from scorbot_gym import seeds
    from scorbot_gym.cli._args import non_negative_float, non_negative_int, positive_int
    from scorbot_gym.experiments.outputs import Outputs, add_overwrite_option

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--demos", type=positive_int, default=200)
    p.add_argument("--dart-sigma", type=non_negative_float, default=0.2)
    p.add_argument("--dagger-rounds", type=non_negative_int, default=8)
    p.add_argument("--dagger-episodes", type=positive_int, default=80)
    p.add_argument("--fit-steps", type=positive_int, default=6000)
    p.add_argument(
        "--no-sync-expert",
        action="store_true",
        help="DAgger labels from the plain scripted controller (its phase timer runs on even "
        "when the learner did not close the fingers)",
    )
    p.add_argument(
        "--episodes", type=positive_int, default=110, help="evaluation episodes per policy"
    )
    p.add_argument("--eval-seed", type=int, default=seeds.TEST.start, help="first evaluation seed")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--dataset", default=None, help="Minari dataset of demonstrations")
    p.add_argument("--beta", type=non_negative_float, default=0.5, help="DAgger's first beta")
    p.add_argument(
        "--pose-window",
        type=non_negative_int,
        default=0,
        help="fresh estimates the policy remembers (HistorySpec.pose_window; 0: none)",
    )
    p.add_argument(
        "--pose-dispersion",
        action="store_true",
        help="the window's summary includes the estimates' disagreement "
        "(HistorySpec.pose_dispersion; needs --pose-window)",
    )
    p.add_argument(
        "--stall-steps",
        type=non_negative_int,
        default=0,
        help="the policy sees how long its TCP has been still, up to this many steps "
        "(HistorySpec.stall_steps; 0: not)",
    )
    p.add_argument(
        "--expert-keeps-close",
        action="store_true",
        help="the DAgger labeller's decision to close stands until the learner closes "
        "(ImitationConfig.expert_keeps_close)",
    )
    p.add_argument(
        "--object-features",
        choices=("class", "grasp_frame"),
        default="class",
        help="what the policy is told of the object besides its pose: its class (one-hot over "
        "the catalogue) or its grasp frame, derived from any object's mesh "
        "(scorbot_gym.policies.object_features; default class)",
    )
    p.add_argument(
        "--objects",
        default=None,
        help="what the training episodes draw from, comma-separated: catalogue, object names, "
        "heldout:training (primitive shapes never tested; scorbot_gym.assets.heldout_objects); "
        "default: the catalogue",
    )
    p.add_argument(
        "--init-policy",
        default=None,
        help="fine-tune this saved imitation policy (learned: the shipped one) instead of "
        "training from scratch",
    )
    p.add_argument(
        "--poses",
        default="oracle",
        help="comma-separated learner pose conditions: oracle, noisy@S[:Y[:D]], manifold",
    )
    p.add_argument(
        "--out",
        type=Path,
        default=None,
        help="policy folder to write (default: runs/learned_policy-<time>/policy; with "
        "--skip-training, the folder to evaluate)",
    )
    p.add_argument(
        "--json", type=Path, default=None, help="results (default: beside the policy folder)"
    )
    p.add_argument(
        "--config",
        default=None,
        help="store the run as this named variant of --json (default: the file's main run)",
    )
    p.add_argument("--skip-training", action="store_true", help="evaluate --out as it is")
    add_overwrite_option(p)
    args = p.parse_args(argv)
    outputs = Outputs("learned_policy", args.overwrite)
    try:  # before any work: a usage error, not a file replaced
        if args.skip_training:
            if args.out is None or not (Path(args.out) / "policy.json").is_file():
                raise ValueError("--skip-training evaluates --out: name a policy folder")
        else:
            args.out = outputs.path(args.out, "policy", "--out")
        args.json = outputs.path(args.json, "learned_policy.json", "--json")
        from scorbot_gym.objects import CATALOGUE

        catalogue = tuple(CATALOGUE)  # what the evaluation draws from, whatever trains
        train_objects = None
        if args.objects is not None:
            from scorbot_gym.assets import heldout_objects

            train_objects = []
            for item in (v for v in args.objects.split(",") if v):
                if item == "catalogue":
                    train_objects += [n for n in catalogue if n not in train_objects]
                elif item.startswith("heldout:"):
                    train_objects += heldout_objects.install(item.split(":", 1)[1])
                elif item in CATALOGUE:
                    train_objects.append(item)
                else:
                    raise ValueError(
                        f"--objects: unknown {item!r}; valid: catalogue, heldout:"
                        f"{' / heldout:'.join(heldout_objects.GROUPS)}, or {', '.join(CATALOGUE)}"
                    )
        demos = None
        if args.dataset and not args.skip_training:
            from scorbot_gym.rl.datasets import read_dataset

            demos = read_dataset(args.dataset)
            have = demos.settings.get("action_type", "cartesian")
            if have != "cartesian":
                raise ValueError(
                    f"--dataset {args.dataset} holds {have} actions; this benchmark trains "
                    "the cartesian env (record it with scorbot-gym demos --action-type cartesian)"
                )
    except (ValueError, FileNotFoundError) as exc:
        p.error(str(exc))

    from pose.fileio import write_result
    from scorbot_gym.policies.imitation import HistorySpec, ImitationPolicy
    from scorbot_gym.rl.imitation import ImitationConfig, make_learner_envs, train_imitation

    if not args.skip_training:
        config = ImitationConfig(
            demos=args.demos,
            dart_sigma=args.dart_sigma,
            dagger_rounds=args.dagger_rounds,
            dagger_episodes=args.dagger_episodes,
            fit_steps=args.fit_steps,
            seed=args.seed,
            sync_expert=not args.no_sync_expert,
            expert_keeps_close=args.expert_keeps_close,
            poses=tuple(v for v in args.poses.split(",") if v),
            beta=args.beta,
            init_policy=args.init_policy,
            object_features=args.object_features,
            objects=train_objects,
            history=HistorySpec(
                pose_window=args.pose_window,
                pose_dispersion=args.pose_dispersion,
                stall_steps=args.stall_steps,
            ),
        )
        envs = make_learner_envs(config)
        try:
            policy, _ = train_imitation(envs, config, demos, progress=print)
        finally:
            for env in envs:
                env.close()
        policy.save(args.out)
        print(f"policy saved to {args.out}")
    policy = ImitationPolicy.load(args.out)
    training = policy.meta["training"]
    arms = {
        "learned": _evaluate("learned", str(args.out), args.episodes, args.eval_seed, catalogue),
        "scripted": _evaluate("scripted", "scripted", args.episodes, args.eval_seed, catalogue),
    }
    size_kb = sum(f.stat().st_size for f in Path(args.out).iterdir()) / 1024
    out = {
        "description": "stand-alone imitation policy (BC + DART + DAgger, oracle pose labels) "
        "vs the scripted controller, same seeds, whole catalogue, oracle pose, cartesian actions",
        "uses_scripted_controller": policy.meta["uses_scripted_controller"],
        "learner_poses": training.get("learner_poses", ["oracle"]),
        "eval_seeds": [args.eval_seed, args.eval_seed + args.episodes - 1],
        "arms": arms,
        "training": {
            k: training[k]
            for k in (
                "demonstration_episodes",
                "dagger_episodes",
                "env_steps",
                "labelled_steps",
                "wall_time_s",
                "rounds",
                "config",
            )
        },
        "policy_size_kb": round(size_kb, 1),
        "policy": str(args.out),
        "trained_by": policy.meta.get("trained_by", "not recorded"),
        "provenance": policy.meta.get("provenance", "not recorded"),
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform()},
    }
    write_result(args.json, out, args.config)
    print(f"results written to {args.json}" + (f" (config {args.config!r})" if args.config else ""))


if __name__ == "__main__":
    main()
