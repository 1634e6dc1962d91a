"""``scorbot-gym compare``: scripted vs learned policies on the same seeds, with paired CIs."""

from __future__ import annotations

import argparse
from pathlib import Path

from scorbot_gym.cli._args import add_name_list, non_negative_int, positive_int


def _floats(text: str) -> list[float]:
    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected comma-separated numbers (metres), got {text!r}"
        ) from None


def _names(text: str) -> list[str]:
    return [v.strip() for v in text.split(",") if v.strip()]


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "compare",
        help="compare policies (scripted, rl, random, a policy directory) on paired seeds",
        description="Run every policy under every pose condition on the same episode seeds and "
        "print each arm's success rate (95% Wilson interval), steps to success and failure "
        "causes, and each policy's difference from the first (paired 95% interval, McNemar's "
        "test). --json and --png write the report and a per-object / per-noise plot.",
    )
    from scorbot_gym.objects import CATALOGUE  # the valid names, for this sub-command only

    p.add_argument(
        "--policies",
        type=_names,
        default=["scripted", "rl"],
        help="comma-separated: scripted, rl (the shipped policy), random, or a "
        "policy directory from `scorbot-gym train`; differences are against the first "
        "(default scripted,rl)",
    )
    p.add_argument(
        "--pose",
        type=_names,
        default=["oracle"],
        help="comma-separated pose conditions: oracle (ground truth), noisy (ground truth + "
        "seeded noise, 1 cm unless --noise), manifold (the pose-manifold estimator on camera "
        "images) (default oracle)",
    )
    p.add_argument(
        "--noise",
        type=_floats,
        default=[],
        help="pose-noise levels (position std in metres, e.g. 0.005,0.01,0.02); each "
        "adds a noisy_oracle condition",
    )
    p.add_argument(
        "--pose-model",
        type=Path,
        default=None,
        help="model file from `scorbot-gym pose train` for --pose manifold (default: the "
        "default models for the top camera, trained on first use and cached)",
    )
    p.add_argument(
        "--episodes", type=positive_int, default=50, help="episodes per arm (default 50)"
    )
    p.add_argument(
        "--seed", type=int, default=0, help="seed of the first episode; every arm runs the same"
    )
    add_name_list(p, "--objects", CATALOGUE, "objects (default: the whole catalogue)")
    p.add_argument(
        "--action-type",
        choices=("cartesian", "joint"),
        default="cartesian",
        help="for scripted/random arms (a learned policy fixes its own)",
    )
    p.add_argument(
        "--estimate-every",
        type=non_negative_int,
        default=1,
        help="re-estimate the pose every K steps (0: once per episode, at reset; default 1)",
    )
    p.add_argument("--json", type=Path, default=None, help="write the report as JSON here")
    p.add_argument("--png", type=Path, default=None, help="write the comparison plot here")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=run)


def format_report(report: dict) -> str:
    from scorbot_gym.evaluation.compare import policy_label

    lines = [f"{'policy':<20} {'pose':<14} {'success':>8}  {'95% CI':<15} {'steps':>6}  failures"]
    for r in report["results"]:
        lo, hi = r["ci95"]
        steps = r["median_steps_to_success"]
        fails = ", ".join(f"{k} {v}" for k, v in r["failure_causes"].items() if v) or "-"
        lines.append(
            f"{policy_label(r['policy']):<20} {r['pose']:<14} {r['success_rate']:>8.1%}  "
            f"{lo:.1%} - {hi:.1%}  {'-' if steps is None else f'{steps:.0f}':>6}  {fails}"
        )
    for d in report["differences"]:
        lo, hi = d["ci95"]
        lines.append(
            f"{policy_label(d['a'])} - {policy_label(d['b'])} ({d['pose']}): {d['diff']:+.1%} "
            f"(95% CI {lo:+.1%} to {hi:+.1%}, McNemar p={d['mcnemar_p']:.3g})"
        )
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    from pose.fileio import atomic_write_json
    from scorbot_gym.evaluation.compare import compare, plot_comparison

    if args.pose_model is not None and not args.pose_model.is_file():
        raise FileNotFoundError(f"--pose-model {args.pose_model}: no such file")
    report = compare(
        args.policies,
        args.pose,
        args.episodes,
        seed=args.seed,
        noise=args.noise,
        pose_model=args.pose_model,
        objects=args.objects,
        action_type=args.action_type,
        estimate_every=args.estimate_every,
        progress=not args.no_progress,
    )
    print(format_report(report))
    if args.json:
        atomic_write_json(args.json, report)
        print(f"report written to {args.json}")
    if args.png:
        plot_comparison(report, args.png)
        print(f"plot written to {args.png}")
    return 0
