"""``scorbot-gym pose train|eval``: fit pose-manifold models on rendered views and score them.

``train`` renders (or reads from the cache) a grid of resting faces x headings, each at random
table positions, for every object, fits one :class:`pose.estimator.PoseManifoldEstimator` per
object and writes them to one model file. ``eval`` renders held-out random poses with synthetic
occlusion and prints, per occlusion level, a table of the BOP-style errors (``--json`` writes
the same numbers).
"""

from __future__ import annotations

import argparse
import os

from pose.fileio import atomic_write_json
from pose.model_set import PoseModelSet
from scorbot_gym.evaluation.pose import evaluate, format_tables
from scorbot_gym.perception.training import train_models

DEFAULT_MODEL = "pose_models.npz"


def _positive_int(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 1:
        raise argparse.ArgumentTypeError(f"--jobs takes a positive integer, got {text!r}")
    return n


def _occlusion_list(text: str) -> list[float]:
    try:
        vals = [float(v) / 100.0 for v in text.split(",") if v.strip()]
    except ValueError as exc:
        raise argparse.ArgumentTypeError(
            f"--occlusion takes comma-separated percentages like 0,25,50,75, got {text!r}"
        ) from exc
    if not vals or any(not 0 <= v <= 0.95 for v in vals):
        raise argparse.ArgumentTypeError(f"occlusion percentages must be in 0..95, got {text!r}")
    return vals


def run_train(args: argparse.Namespace) -> int:
    objects = [o for part in (args.objects or []) for o in part.split(",") if o]
    params = {"bunches__n_bunches": args.n_bunches}
    if args.no_refine:
        params["refiner"] = None
    models, info = train_models(
        objects, args.views, args.camera, args.width, args.height, args.seed,
        args.cache_dir, args.jobs, not args.quiet, params,
    )  # fmt: skip
    models.save(args.out)
    for name in models.object_names:
        i = info[name]
        timing = f"render {i['render_s']:.1f} s  fit {i['fit_s']:.1f} s"
        print(f"{name:<18} {i['views']:>5} views  {timing}")
    print(f"wrote {args.out} ({len(models.object_names)} objects, {info['total_s']:.1f} s)")
    return 0


def run_eval(args: argparse.Namespace) -> int:
    models = PoseModelSet.load(args.model)
    if args.no_refine:
        for est in models.estimators.values():
            est.set_params(refiner=None)
    objects = [o for part in (args.objects or []) for o in part.split(",") if o]
    results = evaluate(
        models, args.occlusion, args.views, args.seed, objects or None, args.cache_dir,
        not args.quiet,
    )  # fmt: skip
    results["model"] = str(args.model)
    print(format_tables(results))
    if args.json:
        atomic_write_json(args.json, results)
        print(f"\nwrote {args.json}")
    return 0


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("pose", help="train and evaluate the pose-manifold estimator")
    sub = p.add_subparsers(dest="pose_command", metavar="ACTION")
    sub.required = True

    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--objects", nargs="*", help="object names (default: the catalogue)")
    common.add_argument("--cache-dir", default=None, help="view cache (default ~/.cache/...)")
    common.add_argument("--quiet", action="store_true", help="no progress bars")

    t = sub.add_parser("train", parents=[common], help="fit one estimator per object")
    t.add_argument("--views", type=int, default=None, help="training views per object")
    t.add_argument("--out", default=DEFAULT_MODEL, help=f"model file (default {DEFAULT_MODEL})")
    t.add_argument("--camera", default="top")
    t.add_argument("--width", type=int, default=640)
    t.add_argument("--height", type=int, default=480)
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--n-bunches", type=int, default=8)
    t.add_argument("--no-refine", action="store_true", help="pure manifold regressor output")
    t.add_argument(
        "--jobs",
        type=_positive_int,
        default=os.cpu_count() or 1,
        help=f"objects trained in parallel processes (default: the CPU count, {os.cpu_count()})",
    )
    t.set_defaults(func=run_train)

    e = sub.add_parser("eval", parents=[common], help="score a model on held-out poses")
    e.add_argument("--model", required=True, help="model file written by `pose train`")
    e.add_argument(
        "--occlusion",
        type=_occlusion_list,
        default=[0.0, 0.25, 0.5, 0.75],
        help="percent of the object's mask hidden, comma-separated (default 0,25,50,75)",
    )
    e.add_argument("--views", type=int, default=30, help="test views per object and level")
    e.add_argument("--seed", type=int, default=1)
    e.add_argument("--json", default=None, help="also write the numbers to this JSON file")
    e.add_argument("--no-refine", action="store_true", help="score the pure manifold output")
    e.set_defaults(func=run_eval)
