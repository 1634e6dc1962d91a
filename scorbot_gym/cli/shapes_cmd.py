"""``scorbot-gym shapes eval``: shape recognition accuracy of FLR, k-NN and SVM.

By default the silhouettes are rendered from the object catalogue (cached on disk); ``--data``
takes an MPEG-7 CE-Shape-1 or ETH-80 folder instead (layout auto-detected or ``--layout``).
ETH-80 is split by whole object instances, the others by stratified random sampling.
"""

from __future__ import annotations

import argparse
import time

from scorbot_gym.cli._args import add_name_list


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "shapes", help="silhouette shape recognition (Fourier + ART + affine moments; FLR)"
    )
    sub = parser.add_subparsers(dest="shapes_command", metavar="ACTION")
    sub.required = True
    sub.add_parser(
        "eval",
        help="held-out accuracy of FLR, k-NN and SVM, with confusion matrices",
        fill=add_eval_arguments,
    )
    return parser


def add_eval_arguments(ev: argparse.ArgumentParser) -> None:
    from scorbot_gym.objects import CATALOGUE

    ev.add_argument("--data", metavar="DIR", help="MPEG-7 or ETH-80 folder (default: render)")
    ev.add_argument("--layout", choices=("auto", "mpeg7", "eth80"), default="auto")
    ev.add_argument("--json", metavar="PATH", help="write the figures as JSON here")
    ev.add_argument("--png", metavar="PATH", help="write the confusion matrices here")
    ev.add_argument("--seed", type=int, default=0, help="seed of rendering, split and FLR")
    ev.add_argument(
        "--per-object", type=int, default=200, metavar="N",
        help="rendered silhouettes per catalogue object (default 200)",
    )  # fmt: skip
    add_name_list(ev, "--objects", CATALOGUE, "rendered data: these catalogue objects only")
    ev.add_argument("--test-size", type=float, default=0.5, help="held-out fraction (0.5)")
    ev.add_argument(
        "--with-size", action="store_true",
        help="rendered data only: add the metric size from the depth camera as a feature",
    )  # fmt: skip
    ev.add_argument("--no-tune", action="store_true", help="skip the CV grid search")
    ev.add_argument(
        "--max-side", type=int, default=256, help="downscale dataset images to this side"
    )
    ev.set_defaults(func=run)


def load_silhouettes(args: argparse.Namespace):
    """The silhouette set the arguments ask for, and a one-line description of it."""
    if args.data:
        from pose.shape.datasets import detect_layout, load_dataset

        if args.with_size or args.objects:
            raise ValueError(
                "--with-size and --objects apply to rendered silhouettes; drop them or --data"
            )
        layout = detect_layout(args.data) if args.layout == "auto" else args.layout
        data = load_dataset(args.data, layout, max_side=args.max_side)
        return data, layout, f"{layout} silhouettes from {args.data}"
    from scorbot_gym.data.shapes import render_catalogue_silhouettes

    if args.per_object < 4:
        raise ValueError(f"--per-object must be >= 4, got {args.per_object}")
    objects = args.objects or None
    if objects is not None and len(objects) < 2:
        raise ValueError(f"--objects needs at least 2 objects to compare, got {args.objects!r}")
    data = render_catalogue_silhouettes(objects, n_per_object=args.per_object, seed=args.seed)
    return data, "rendered", f"{args.per_object} rendered silhouettes per catalogue object"


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from pose.fileio import atomic_write_json
    from pose.shape.descriptors import shape_descriptors
    from pose.shape.evaluation import evaluate, plot_confusions
    from scorbot_gym.outputs import check_output_file

    if args.json:  # before the silhouettes are rendered or read
        check_output_file(args.json, "--json", (".json", ".json.gz"))
    if args.png:
        check_output_file(args.png, "--png", (".png",))
    t0 = time.perf_counter()
    data, layout, what = load_silhouettes(args)
    X = shape_descriptors(data.masks)
    features = "shape descriptor (73)"
    if args.with_size:
        X = np.c_[X, data.extras["metric_size"]]
        features = "shape descriptor (73) + metric size"
    groups = data.groups if layout == "eth80" else None
    result = evaluate(X, data.labels, seed=args.seed, test_size=args.test_size,
                      groups=groups, tune=not args.no_tune)  # fmt: skip
    result.update(dataset=what, layout=layout, features=features,
                  total_s=round(time.perf_counter() - t0, 2))  # fmt: skip

    print(f"{what}: {len(data)} silhouettes, {len(result['classes'])} classes, {features}")
    print(f"split {result['split']}: {result['n_train']} train / {result['n_test']} test")
    for name, r in result["classifiers"].items():
        params = ", ".join(f"{k}={v}" for k, v in r["best_params"].items()) or "defaults"
        print(f"  {name:4s} accuracy {100 * r['accuracy']:6.2f} %   ({params})")
    print(f"FLR - best baseline ({result['best_baseline']}): "
          f"{result['flr_minus_best_baseline_points']:+.2f} points")  # fmt: skip
    if args.json:
        atomic_write_json(args.json, result)
        print(f"wrote {args.json}")
    if args.png:
        plot_confusions(result, args.png, title=what)
        print(f"wrote {args.png}")
    return 0
