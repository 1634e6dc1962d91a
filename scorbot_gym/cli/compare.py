"""``scorbot-gym compare``: scripted vs learned policies on the same seeds, with paired CIs."""

from __future__ import annotations

import argparse
from pathlib import Path

from scorbot_gym.cli._args import (
    add_episode_workers,
    add_name_list,
    non_negative_int,
    positive_int,
)
from scorbot_gym.names import POLICIES


def _noise_levels(text: str) -> list[str]:
    """``S`` or ``S:Y`` items (position std in metres, heading std in degrees), checked here;
    :func:`scorbot_gym.evaluation.compare.noise_level` reads them."""
    levels = [v.strip() for v in text.split(",") if v.strip()]
    for v in levels:
        parts = v.split(":")
        try:
            if len(parts) > 2 or any(float(x) < 0 for x in parts):
                raise ValueError
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"expected comma-separated S or S:Y (position std in metres, heading std in "
                f"degrees, both >= 0; e.g. 0.01,0.02:20), got {text!r}"
            ) from None
    return levels


def _names(text: str) -> list[str]:
    return [v.strip() for v in text.split(",") if v.strip()]


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "compare",
        help="compare policies (scripted, rl, learned, random, a policy or run folder) on "
        "paired seeds",
        description="Run every policy under every pose condition on the same episode seeds and "
        "print each arm's success rate (95% Wilson interval), its difference from scripted "
        "(paired 95% interval, McNemar's test), steps to success (median and quartiles), failure "
        "causes and how each policy was trained. --json writes the report (keys documented in "
        "scorbot_gym.evaluation.compare), --png the figure (success per arm, the paired "
        "differences as a forest plot, per object, one axis per kind of pose noise).",
    )
    from scorbot_gym.objects import CATALOGUE  # the valid names, for this sub-command only

    p.add_argument(
        "--policies",
        type=_names,
        default=["scripted", "rl"],
        help=f"comma-separated: built-in policies ({', '.join(POLICIES)}; `scorbot-gym "
        "rollout --help` says what each is) or policy folders (policy.json) / `scorbot-gym "
        "train` run folders; differences are against scripted (else the first) (default "
        "scripted,rl)",
    )
    p.add_argument(
        "--pose",
        type=_names,
        default=["oracle"],
        help="comma-separated pose conditions: oracle (ground truth), noisy (ground truth + "
        "seeded noise, 1 cm unless --noise), manifold (the pose-manifold estimator on camera "
        "images, no privileged input: background masks, recognised identity), chance (the "
        "rotation-blind chance level: manifold with the estimator swapped for a constant "
        "rotation fitted on the default models' views; the position still comes from the "
        "image), occluded or occluded@D[:HIGH] (ground truth lost while the hand is within "
        "6-20 cm, or D-HIGH m, of the object, as a camera loses it) (default oracle)",
    )
    p.add_argument(
        "--noise",
        type=_noise_levels,
        default=[],
        help="pose-noise levels, each adds a noisy_oracle condition: S (position std in "
        "metres, heading std S*500 degrees: 1 cm with 5 deg) or S:Y (heading std Y degrees), "
        "e.g. 0.01,0:20,0.02:0",
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
        "--cartesian-ik",
        choices=("closed_form", "dls"),
        default="closed_form",
        help="how Cartesian actions become joint targets (dls: damped least squares every "
        "step, as results before 2026-11-28; default closed_form)",
    )
    p.add_argument(
        "--estimate-every",
        type=non_negative_int,
        default=1,
        help="re-estimate the pose every K steps (0: once per episode, at reset; default 1)",
    )
    add_episode_workers(p)
    p.add_argument("--json", type=Path, default=None, help="write the report as JSON here")
    p.add_argument("--png", type=Path, default=None, help="write the comparison figure here")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=run)


def format_report(report: dict) -> str:
    """One line per arm (success, interval, difference to the reference, steps to success as
    median [IQR], failures), then each policy's training."""
    ref = "vs " + report.get("reference", "first")
    head = f"{'policy':<18} {'pose':<15} {'success':>7}  {'95% CI':<14} {ref:<32} "
    head += f"{'steps':<12} failures"
    lines = [head]
    for r in report["results"]:
        lo, hi = r["ci95"]
        d = r.get("vs_reference")
        diff = "-"
        if d:
            dlo, dhi = d["ci95"]
            diff = f"{d['diff']:+.1%} ({dlo:+.1%}, {dhi:+.1%}) p={d['mcnemar_p']:.2g}"
        s = r.get("steps_to_success")
        steps = "-" if not s else f"{s['median']:.0f} [{s['q25']:.0f}-{s['q75']:.0f}]"
        fails = ", ".join(f"{k} {v}" for k, v in r["failure_causes"].items() if v) or "-"
        lines.append(
            f"{r.get('label', r['policy']):<18} {r['pose']:<15} {r['success_rate']:>7.1%}  "
            f"{lo:.1%} - {hi:.1%}  {diff:<32} {steps:<12} {fails}"
        )
    for arm in report.get("arms", {}).values():
        t = arm["training"]
        known = [
            f"{t['algo']}" if t["algo"] else None,
            f"{t['demonstration_episodes']} demonstrations"
            if t["demonstration_episodes"]
            else None,
            None if t["env_steps"] is None else f"{t['env_steps']:,} env steps",
            None if t["wall_time_s"] is None else f"{t['wall_time_s']:,.0f} s wall time",
            None if t["seeds"] is None else "seeds " + ",".join(map(str, t["seeds"])),
        ]
        known_text = ", ".join(k for k in known if k)
        lines.append(
            f"{arm['label']}: trained from {t['trained_from']}"
            + (f" ({known_text})" if known_text else "")
        )
    return "\n".join(lines)


def check_outputs(args: argparse.Namespace) -> None:
    """``--json`` and ``--png`` writable (one-line errors), before any episode runs."""
    from scorbot_gym.outputs import check_output_file

    if args.json is not None:
        check_output_file(args.json, "--json", (".json", ".json.gz"))
    if args.png is not None:
        check_output_file(args.png, "--png", (".png",))


def run(args: argparse.Namespace) -> int:
    from pose.fileio import atomic_write_json
    from scorbot_gym.evaluation.compare import compare, plot_comparison

    if args.pose_model is not None and not args.pose_model.is_file():
        raise FileNotFoundError(f"--pose-model {args.pose_model}: no such file")
    check_outputs(args)
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
        jobs=args.jobs,
        ray=args.ray,
        cartesian_ik=args.cartesian_ik,
    )
    print(format_report(report))
    if args.json:
        atomic_write_json(args.json, report)
        print(f"report written to {args.json}")
    if args.png:
        plot_comparison(report, args.png)
        print(f"plot written to {args.png}")
    return 0
