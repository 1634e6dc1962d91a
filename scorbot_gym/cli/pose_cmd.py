"""``scorbot-gym pose train|eval|ablate``: fit pose-manifold models on rendered views, score
them, and run ablation sweeps.

``train`` renders (or reads from the cache) a grid of resting faces x headings, each at random
table positions, for every object, fits one
:class:`~pose.manifold.estimator.PoseManifoldEstimator` per object and writes them to one model
file. ``eval`` renders held-out random poses with synthetic
occlusion and prints, per occlusion level, a table of the BOP-style errors (``--json`` writes
the same numbers). ``ablate`` runs a protocol x estimators x occlusion sweep
(:mod:`scorbot_gym.experiments`) and writes the seed's Fig. 3 (``--png``), the per-level
records (``--json``) and optionally a BOP dataset of the test views and estimates (``--bop``).
"""

from __future__ import annotations

import argparse
import os

from scorbot_gym.cli._args import add_name_list

DEFAULT_MODEL = "pose_models.npz"
#: ``pose ablate --occlusion`` when not given; parsed by ``run_ablate``, since the parser lives
#: with the sweep machinery, which ``--help`` and argument errors should not import
DEFAULT_ABLATE_OCCLUSION = "0:95:5"


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
    from scorbot_gym.outputs import check_output_file
    from scorbot_gym.perception.training import train_models

    if args.defaults:
        return run_train_defaults(args)
    check_output_file(args.out, "--out", (".npz",))  # before any view is rendered or fitted
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


#: ``pose train`` options that choose what is trained: ``--defaults`` builds what the main job
#: uses, so it takes none of them (their values when not given)
_TRAIN_CHOICES = {
    "objects": None, "views": None, "out": DEFAULT_MODEL, "camera": "top", "width": 640,
    "height": 480, "seed": 0, "n_bunches": 8, "no_refine": False, "cache_dir": None,
}  # fmt: skip


def run_train_defaults(args: argparse.Namespace) -> int:
    """``pose train --defaults``: build, into the cache, what the main job builds on first
    use (:mod:`scorbot_gym.perception.defaults`), and say where it is."""
    from scorbot_gym.data import default_cache_dir
    from scorbot_gym.perception import defaults

    given = [k for k, v in _TRAIN_CHOICES.items() if getattr(args, k) != v]
    if given:
        flags = ", ".join("--" + k.replace("_", "-") for k in given)
        raise ValueError(
            f"--defaults builds the models the main job uses (into $SCORBOT_GYM_CACHE or "
            f"~/.cache/scorbot-gym) and takes only --jobs and --quiet, got {flags}"
        )
    entries = defaults.build(jobs=args.jobs, progress=not args.quiet)
    print(f"default models ready in {default_cache_dir()}:")
    print("\n".join(defaults.status_lines(entries)))
    return 0


def run_eval(args: argparse.Namespace) -> int:
    from pose.fileio import atomic_write_json
    from pose.model_set import PoseModelSet
    from scorbot_gym.evaluation.pose import evaluate, format_tables
    from scorbot_gym.outputs import check_output_file

    if args.json:
        check_output_file(args.json, "--json", (".json", ".json.gz"))
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


def sweep_runner(jobs: int | None, ray: str | None):
    """The runner of ``pose ablate``: Ray tasks with ``ray`` ("local" or an address), else a
    local process pool with ``jobs`` workers, by default one per core this process may use."""
    from scorbot_gym.experiments import LocalRunner, RayRunner

    if ray is not None:
        return RayRunner(None if ray == "local" else ray, num_cpus=jobs)
    return LocalRunner(jobs or len(os.sched_getaffinity(0)))


def _estimator_list(text: str) -> list[str]:
    from scorbot_gym.experiments.spec import EstimatorSpec, split_estimators

    try:
        return [str(EstimatorSpec.parse(e)) for e in split_estimators(text)]
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from exc


def _estimator_spec(text: str) -> str:
    specs = _estimator_list(text)
    if len(specs) != 1:
        raise argparse.ArgumentTypeError(f"one estimator spec expected, got {text!r}")
    return specs[0]


def _occlusion_range(text: str) -> tuple[float, ...]:
    from scorbot_gym.experiments.spec import parse_occlusions

    try:
        return parse_occlusions(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from exc


def run_ablate(args: argparse.Namespace) -> int:
    from scorbot_gym.data.perturbations import Perturbation
    from scorbot_gym.evaluation.bop import export_ablation
    from scorbot_gym.experiments import SweepSpec, ablate, write_report
    from scorbot_gym.experiments.aggregate import (
        format_results,
        paired_differences,
        report_tables,
    )
    from scorbot_gym.outputs import check_output_file, check_output_folder

    if args.paired is not None and args.paired not in args.estimators:
        raise ValueError(f"--paired {args.paired!r} is not among --estimators {args.estimators}")
    if args.json:
        check_output_file(args.json, "--json", (".json", ".json.gz"))
    if args.png:
        check_output_file(args.png, "--png", (".png",))
    if args.bop:
        check_output_folder(args.bop, "--bop")
    objects = tuple(o for part in (args.objects or []) for o in part.split(",") if o)
    occlusion = args.occlusion
    if occlusion is None:  # the protocol's levels (0:95:5; clutter: its measured-occlusion bins)
        from scorbot_gym.data.protocols import get_protocol

        occlusion = get_protocol(args.protocol).occlusions
    spec = SweepSpec(
        args.protocol, tuple(args.estimators), occlusion, objects, args.seed, args.width,
        args.height, args.test_views, args.train_stride, Perturbation.parse(args.perturb),
    )  # fmt: skip
    report = ablate(spec, sweep_runner(args.jobs, args.ray), args.cache_dir)
    if args.paired is not None:
        report["paired"] = paired_differences(report["view_errors"], args.paired)
    print(format_results(report["results"], report["chance"]))
    for table in report_tables(report):
        print("\n" + table)
    st = report["stats"]
    print(
        f"\n{st['jobs']} models: {st['fits']} fitted, {st['model_cache_hits']} from cache;"
        f" {st['trials_run']} trials run, {st['trials_cached']} from the cache ({st['wall_s']} s)"
    )
    for f in report["fit_errors"]:  # their test views count as failures
        print(f"not fitted: {f['estimator']} on {f['object']}: {f['error']}")
    write_report(report, args.json, args.png)
    for path in (args.json, args.png):
        if path:
            print(f"wrote {path}")
    if args.bop:
        print(f"wrote BOP dataset {export_ablation(report, args.bop, cache_dir=args.cache_dir)}")
    return 0


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("pose", help="train and evaluate the pose-manifold estimator")
    sub = p.add_subparsers(dest="pose_command", metavar="ACTION")
    sub.required = True
    sub.add_parser("train", help="fit one estimator per object", fill=_add_train_arguments)
    sub.add_parser("eval", help="score a model on held-out poses", fill=_add_eval_arguments)
    sub.add_parser(
        "ablate",
        help="success@5deg vs occlusion for several estimators on one protocol",
        description="Estimators are registered names, optionally with parameters: "
        "manifold,manifold(refiner=None),pca-nn. Results are cached per trial (a rerun resumes).",
        fill=_add_ablate_arguments,
    )


def _add_common_arguments(p: argparse.ArgumentParser) -> None:
    from scorbot_gym.objects import CATALOGUE

    add_name_list(p, "--objects", CATALOGUE, "object names (default: the catalogue)")
    p.add_argument("--cache-dir", default=None, help="view cache (default ~/.cache/...)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")


def _add_train_arguments(t: argparse.ArgumentParser) -> None:
    from scorbot_gym.names import FIXED_CAMERAS, MOVING_CAMERAS

    _add_common_arguments(t)
    t.add_argument(
        "--defaults", action="store_true",
        help="build the default models that rollout/compare train on first use, into the cache",
    )  # fmt: skip
    t.add_argument("--views", type=int, default=None, help="training views per object")
    t.add_argument("--out", default=DEFAULT_MODEL, help=f"model file (default {DEFAULT_MODEL})")
    t.add_argument(
        "--camera",
        choices=[*FIXED_CAMERAS, *MOVING_CAMERAS],
        default="top",
        help="camera the models are trained for (eye_in_hand: from the arm's home pose)",
    )
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


def _add_eval_arguments(e: argparse.ArgumentParser) -> None:
    _add_common_arguments(e)
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


def _add_ablate_arguments(a: argparse.ArgumentParser) -> None:
    from scorbot_gym.names import PROTOCOLS

    _add_common_arguments(a)
    a.add_argument("--protocol", required=True, choices=PROTOCOLS)
    a.add_argument(
        "--estimators", type=_estimator_list, default=["manifold"],
        help="comma-separated estimator specs NAME or NAME(param=value, ...) (default manifold)",
    )  # fmt: skip
    a.add_argument(
        "--occlusion", type=_occlusion_range, default=None,
        help=f"percent levels START:STOP:STEP or a comma list (default {DEFAULT_ABLATE_OCCLUSION}; "
        "clutter: the lower edges of its 10 %% bins of measured occlusion, 0:90:10)",
    )  # fmt: skip
    a.add_argument(
        "--jobs", type=_positive_int, default=None,
        help="parallel worker processes (default: the usable cores, "
        f"{len(os.sched_getaffinity(0))}; with --ray, Ray's CPUs); 1 runs in this process",
    )  # fmt: skip
    a.add_argument(
        "--ray", nargs="?", const="local", default=None, metavar="ADDRESS",
        help="run as Ray tasks: a local instance, or join ADDRESS (auto, ray://host:port)",
    )  # fmt: skip
    a.add_argument("--width", type=int, default=320)
    a.add_argument("--height", type=int, default=240)
    a.add_argument("--seed", type=int, default=0, help="training seed (tests use seed + 1)")
    a.add_argument("--test-views", type=int, default=None,
                   help="first N held-out poses only (clutter: N scenes, binned)")  # fmt: skip
    a.add_argument("--train-stride", type=int, default=1, help="every Nth training view only")
    a.add_argument(
        "--perturb", default=None, metavar="K=V,...",
        help="test-view perturbation, e.g. lighting=0.3,noise_sigma=4,camera_rot_deg=1,seed=0",
    )  # fmt: skip
    a.add_argument(
        "--paired", type=_estimator_spec, default=None, metavar="ESTIMATOR",
        help="compare this estimator view by view with every other one (paired interval, McNemar)",
    )  # fmt: skip
    a.add_argument("--json", default=None, help="write the per-level records here")
    a.add_argument("--png", default=None, help="write success@5deg vs occlusion here")
    a.add_argument("--bop", default=None, metavar="DIR", help="also export a BOP dataset here")
    a.set_defaults(func=run_ablate)
