"""The scripted-vs-learned comparison table: paired seeds, Wilson CIs, paired-difference CIs.

Runs :func:`scorbot_gym.evaluation.compare.compare` for the scripted controller (the
reference) and the learned arms (``--policies``: built-in names such as ``rl``, the shipped
residual, or policy / training-run folders) on the whole catalogue, every arm on the same
seeds, under the oracle pose and the noisy-oracle levels (``S`` metres of position noise with
``S * 500`` degrees of heading noise, or ``S:Y`` for Y degrees). The default levels are the
issue's two: heading σ 20° alone (``0:20``) and position σ 2 cm alone (``0.02:0``), under which
the scripted controller grasped 95 % and 82 % of 44 episodes in ``closed_loop.json``.
``--poses oracle,manifold`` adds the pose-manifold estimator with no privileged input
(background-subtraction masks, recognised identity: the main arm of ``closed_loop.py``; the
default top-camera models, or ``--pose-model``); ``chance`` adds its rotation-blind chance
level (the same source, masks and recognition with the estimator swapped for a constant rotation
fitted on the default models' views: the position still from the image); ``--noise ""`` runs
no noise level.
Writes ``compare.json`` (the report documented in :mod:`scorbot_gym.evaluation.compare`, plus
the machine) and the figure ``compare.png``, into a new ``runs/compare-<time>/`` unless ``--out``
names the file (an existing one only with ``--overwrite``); ``--config NAME`` stores the run as
the variant ``configs[NAME]`` of that file instead (e.g. held-out objects, another pose model),
without a figure, the file's other runs kept. The committed record is rebuilt with ``--out
benchmarks/results/compare.json --overwrite`` (and a variant of it with ``--config NAME`` too).
``--objects heldout:heading`` (or ``heldout:symmetric``) runs on objects outside the catalogue
that no shipped policy trained on (:mod:`scorbot_gym.assets.heldout_objects`).
``--replot`` redraws the figure of ``--out`` (``.json`` or ``.json.gz``) without running an
episode.

    nice -n 5 python benchmarks/compare.py [--policies rl,learned,finetuned,rl_scratch] \
        [--episodes 200] [--poses oracle,manifold,chance] [--noise 0:20,0.02:0] \
        [--pose-model FILE] [--jobs 6]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

#: the first evaluation seed: the start of the test range (scorbot_gym.seeds.TEST), which no
#: training seed range overlaps (the shipped imitation policies, trained before those ranges,
#: used demonstration seeds 0-199 and DAgger seeds from 1,000,000); 50000-50199 are also the
#: seeds of benchmarks/finetune.py, so the two reports agree arm for arm
EVAL_SEED = 50_000  # scorbot_gym.seeds.TEST.start (not imported: --help stays fast)


def main(argv: list[str] | None = None) -> int:
    from scorbot_gym.experiments.outputs import Outputs, add_overwrite_option

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--policies",
        default="rl,learned,finetuned,rl_scratch",
        help="learned arms, comma-separated (scripted is added)",
    )
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument(
        "--seed",
        type=int,
        default=EVAL_SEED,
        help=f"first seed (default {EVAL_SEED}: placements no shipped policy trained on)",
    )
    parser.add_argument("--noise", default="0:20,0.02:0", help="noise levels: S or S:Y")
    parser.add_argument(
        "--poses",
        default="oracle",
        help="oracle, occluded, manifold and/or chance (besides --noise)",
    )
    parser.add_argument("--pose-model", type=Path, default=None, help="manifold model file")
    parser.add_argument(
        "--objects",
        default=None,
        help="catalogue objects, comma-separated, or heldout:heading / heldout:symmetric: "
        "objects outside the catalogue (scorbot_gym.assets.heldout_objects; default: the "
        "whole catalogue)",
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        help="results JSON, the PNG beside it (default: runs/compare-<time>/compare.json)",
    )
    add_overwrite_option(parser)
    parser.add_argument(
        "--config",
        default=None,
        help="store the run as this named variant of --out (default: the file's main run)",
    )
    parser.add_argument(
        "--jobs", type=int, default=1, help="processes (each runs a chunk of an arm's seeds)"
    )
    parser.add_argument(
        "--cartesian-ik",
        choices=("closed_form", "dls"),
        default="closed_form",
        help="the env's IK for Cartesian actions (dls: damped least squares every step, as "
        "every run before 2026-11-28; default closed_form)",
    )
    parser.add_argument(
        "--replot", action="store_true", help="redraw the figure of --out, run nothing"
    )
    args = parser.parse_args(argv)
    if args.replot:
        from pose.fileio import read_json
        from scorbot_gym.evaluation.compare_plot import plot_comparison

        if args.out is None:
            parser.error("--replot needs --out: the report whose figure to redraw")
        png = args.out.with_name(args.out.name.split(".json")[0] + ".png")
        plot_comparison(read_json(args.out), png)
        print(f"written {png}")
        return 0
    objects = None
    if args.objects is not None:  # before any work: a bad name is a usage error
        from scorbot_gym.assets import heldout_objects
        from scorbot_gym.objects import CATALOGUE

        try:
            if args.objects.startswith("heldout:"):
                objects = list(heldout_objects.install(args.objects.split(":", 1)[1]))
            else:
                objects = [o for o in args.objects.split(",") if o]
                unknown = [o for o in objects if o not in CATALOGUE]
                if unknown or not objects:
                    raise ValueError(
                        f"unknown objects {unknown}; valid: {', '.join(CATALOGUE)}, or "
                        f"heldout:{' / heldout:'.join(heldout_objects.GROUPS)}"
                    )
        except ValueError as exc:
            parser.error(f"--objects: {exc}")
    try:  # before any work: an existing file is not replaced unless asked
        args.out = Outputs("compare", args.overwrite).path(
            args.out, "compare.json", companions=[".png"] if args.config is None else []
        )
    except ValueError as exc:
        parser.error(str(exc))
    png = args.out.with_name(args.out.name.split(".json")[0] + ".png")

    import scorbot_gym
    from pose.fileio import write_result
    from scorbot_gym.cli.compare import format_report
    from scorbot_gym.evaluation.compare import compare, plot_comparison

    policies = ["scripted"] + [p for p in args.policies.split(",") if p and p != "scripted"]
    poses = [p for p in args.poses.split(",") if p]
    report = compare(
        policies,
        poses,
        args.episodes,
        seed=args.seed,
        noise=[v for v in args.noise.split(",") if v],
        pose_model=args.pose_model,
        objects=objects,
        progress=False,
        jobs=args.jobs,
        cartesian_ik=args.cartesian_ik,
    )
    report["machine"] = {
        "platform": platform.platform(),
        "cpu_count": os.cpu_count(),
        "jobs": args.jobs,
        "scorbot_gym": scorbot_gym.__version__,
    }
    write_result(args.out, report, args.config)
    print(format_report(report))
    if args.config is None:  # the figure is the main run's
        plot_comparison(report, png)
        print(f"written {args.out} and {png}")
    else:
        print(f"written {args.out} (config {args.config!r})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
