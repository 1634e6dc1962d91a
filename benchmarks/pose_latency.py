"""``predict`` latency on one pinned core, estimators side by side: the issue's 30 ms target.

For each protocol the estimators are fitted per object exactly as ``pose_ablation.py`` fits
them (same sweep code, same model cache: after a sweep nothing is refitted), then one process
pinned to one core, every thread pool at one thread, times ``predict`` on each object's held-out
views (the sweep's test views, 320 × 240) with the estimators interleaved view by view
(:func:`scorbot_gym.experiments.latency.time_predictions`). Writes ``pose_latency.json`` (by
default into a new ``runs/pose_latency-<time>/``; ``--json`` names the file, an existing one
only with ``--overwrite``; ``--config NAME`` stores a variant under ``configs[NAME]``): per
protocol and estimator the median, 90th percentile and maximum per-view time, and the paired
ratio to ``--reference`` on the same views.

    python benchmarks/pose_latency.py    # tilted, side-turntable, top-resting; select vs baselines
    python benchmarks/pose_latency.py --json benchmarks/results/pose_latency.json --overwrite
    python benchmarks/pose_latency.py --protocols tilted --cache-dir /tmp/empty  # training too
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"
os.environ.setdefault("MUJOCO_GL", "egl")

import argparse  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
from dataclasses import replace  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from pose.fileio import write_result  # noqa: E402
from scorbot_gym.data.protocols import held_out_views, protocol_names  # noqa: E402
from scorbot_gym.experiments import LocalRunner, make_jobs, run_sweep, sweep  # noqa: E402
from scorbot_gym.experiments.latency import (  # noqa: E402
    pin_to_one_core,
    stage_timings,
    summarize_latency,
    time_predictions,
)
from scorbot_gym.experiments.trial import default_cache_dir, fitted_model  # noqa: E402

TARGET_MS = 30.0
L = ("manifold-pnp(keypoints__upscale=2, matcher__min_inliers=6, matcher__n_candidates=8, "
     "refiner__correspondences='ratio+global', refiner__keep_margin=0.0)")  # fmt: skip
R = ("manifold-pnp(keypoints__upscale=2, matcher__min_inliers=6, "
     "refiner__correspondences='ratio+global')")  # fmt: skip
# the README's full estimator, the practitioner's baseline it is compared with, the default manifold
DEFAULT_ESTIMATORS = [f'select(estimators=("{L}", "{R}", \'pca-rbf\', \'chance\'))',
                      "sift-pnp(upscale=2)", "manifold"]  # fmt: skip


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--protocols", default="tilted,side-turntable,top-resting")
    ap.add_argument("--estimators", default=None,
                    help="comma-separated specs (default: the README's select, "
                         "sift-pnp(upscale=2), manifold)")  # fmt: skip
    ap.add_argument("--reference", default="sift-pnp(upscale=2)")
    ap.add_argument("--objects", default=None, help="comma-separated (default: the catalogue)")
    ap.add_argument("--views", type=int, default=10, help="held-out views per object (0 %%)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=240)
    ap.add_argument("--jobs", type=int, default=2, help="processes fitting the models")
    ap.add_argument("--cache-dir", default=None,
                    help="an empty one times training from scratch, rendering too")  # fmt: skip
    from scorbot_gym.experiments.outputs import Outputs, add_overwrite_option

    ap.add_argument(
        "--json",
        default=None,
        help="where to write (default: runs/pose_latency-<time>/pose_latency.json; an existing "
        "file is refused without --overwrite)",
    )
    add_overwrite_option(ap)
    ap.add_argument(
        "--config",
        default=None,
        help="store the run as this named variant of --json (default: the file's main run)",
    )
    args = ap.parse_args(argv)
    try:  # before any work: an existing file is not replaced unless asked
        args.json = Outputs("pose_latency", args.overwrite).path(
            args.json, "pose_latency.json", "--json"
        )
    except ValueError as exc:
        ap.error(str(exc))
    protocols = [p for p in args.protocols.split(",") if p]
    unknown = sorted(set(protocols) - set(protocol_names()))
    if unknown:
        ap.error(f"unknown protocols {unknown}; known: {', '.join(protocol_names())}")
    if args.views < 1 or args.repeats < 1:
        ap.error(f"--views and --repeats must be positive, got {args.views} and {args.repeats}")
    objects = tuple(o for o in (args.objects or "").split(",") if o)
    cache = str(args.cache_dir or default_cache_dir())
    try:
        specs = {p: sweep(p, args.estimators or DEFAULT_ESTIMATORS, "0", objects=objects,
                          seed=args.seed, width=args.width, height=args.height,
                          test_views=args.views) for p in protocols}  # fmt: skip
        reference = str(sweep(protocols[0], [args.reference]).estimators[0])
    except ValueError as exc:
        ap.error(str(exc))
    names = list(next(iter(specs.values())).estimators)
    if reference not in names:
        ap.error(f"--reference {args.reference!r} must be one of the timed estimators")

    # 1. fit (or find in the cache) every model, and render every test view, before pinning
    work, fitting = {}, {}
    for protocol, spec in specs.items():
        # one sweep per estimator, so each one's training wall time on --jobs cores is its own
        # (the first also renders the training views when the view cache is cold)
        fitting[protocol] = []
        for est in names:
            one = replace(spec, estimators=(est,))
            stats = run_sweep(one, LocalRunner(args.jobs), cache)["stats"]
            fitting[protocol].append({"estimator": est, **stats})
            print(f"fitted {protocol} {est[:60]}: {stats}")
        for obj in spec.object_names:
            views = held_out_views(protocol, obj, 0.0, seed=args.seed + 1, width=args.width,
                                   height=args.height, cache_dir=cache)[: args.views]  # fmt: skip
            work[protocol, obj] = [lv.view for lv in views]
    # 2. time, one process on one core
    core = pin_to_one_core()
    report: dict = {"estimators": names, "reference": reference, "target_ms": TARGET_MS,
                    "views_per_object": args.views, "repeats": args.repeats, "seed": args.seed,
                    "size": [args.width, args.height], "occlusion": 0.0, "results": [],
                    "skipped": [], "fitting": fitting,
                    "fitting_note": "per estimator: the sweep's fits on --jobs processes; "
                                    "fits=0 where the model cache had them"}  # fmt: skip
    for protocol, spec in specs.items():
        per_view: dict[str, list[np.ndarray]] = {n: [] for n in names}
        per_object, stages = [], {n: {} for n in names}
        jobs = make_jobs(spec, cache)
        for obj in spec.object_names:
            models = {}
            for job in (j for j in jobs if j.object_name == obj):
                try:
                    models[job.estimator] = fitted_model(job)
                except ValueError as exc:  # refused this object's views: no time to take
                    skip = {"protocol": protocol, "object": obj, "error": str(exc)}
                    report["skipped"].append({**skip, "estimator": job.estimator})
            if len(models) < len(names):
                continue  # paired ratios need every estimator on the same views
            ms = time_predictions(models, work[protocol, obj], args.repeats)
            for n in names:
                per_view[n].append(ms[n])
            per_object.append({"object": obj, **{n: round(float(np.median(ms[n])), 2)
                                                 for n in names}})  # fmt: skip
            for n in names:
                for stage, v in stage_timings(models[n], work[protocol, obj]).items():
                    stages[n].setdefault(stage, []).extend(v)
            medians = "  ".join(f"{np.median(ms[n]):6.1f}" for n in names)
            print(f"{protocol:16s} {obj:16s} {medians}")
        if not per_object:
            continue
        rows = summarize_latency({n: np.concatenate(v) for n, v in per_view.items()}, reference)
        for row in rows:
            row.update(protocol=protocol, target_met=row["median_ms"] <= TARGET_MS)
            # the answering estimator's own stage clocks, median over its valid answers
            own = stages[row["estimator"]]
            row["stages_median_ms"] = {k: round(float(np.median(v)), 2) for k, v in own.items()}
            report["results"].append(row)
            print(f"{protocol:16s} median {row['median_ms']:6.1f} ms  p90 {row['p90_ms']:6.1f}  "
                  f"x{row['ratio_to_reference']:.2f} of ref.  {row['estimator'][:60]}")  # fmt: skip
        report.setdefault("per_object_median_ms", {})[protocol] = per_object
    report["machine"] = {"platform": platform.platform(), "python": sys.version.split()[0],
                         "cpu": cpu_model(), "cpus": os.cpu_count(), "pinned_core": core,
                         "threads": 1}  # fmt: skip
    write_result(Path(args.json), report, args.config)
    print(f"wrote {args.json}" + (f" (config {args.config!r})" if args.config else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
