"""The PnP refiner's keep test swept on one fit: success@5° against ``refiner__keep_margin``.

``PnPRefiner`` keeps the matched training view's rotation unless PnP lowers the MSAC cost by
more than ``keep_margin`` px². The margin acts only at ``predict`` time, so each object's model
is fitted once (or read from the sweeps' model cache) and its test views are answered under
every margin (:mod:`scorbot_gym.experiments.predict_params`); every cell is what a full sweep
of that spec gives. This is how the default margin (10 px²) was chosen, on seed 1: the
README's *The keep test* section.

    python benchmarks/keep_margin.py     # seed 1; top-resting, tilted, side-turntable; 0 and 50 %
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

from pose.fileio import atomic_write_json  # noqa: E402
from pose.manifold.refinement import PnPRefiner  # noqa: E402
from scorbot_gym.data.protocols import protocol_names  # noqa: E402
from scorbot_gym.experiments import LocalRunner, aggregate, sweep  # noqa: E402
from scorbot_gym.experiments.plot import plot_success_vs_parameter  # noqa: E402
from scorbot_gym.experiments.predict_params import sweep_predict_param, with_param  # noqa: E402
from scorbot_gym.experiments.spec import EstimatorSpec, parse_occlusions  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
PARAM = "refiner__keep_margin"
R = ("manifold-pnp(keypoints__upscale=2, matcher__min_inliers=6, "
     "refiner__correspondences='ratio+global')")  # fmt: skip
MARGINS = "0,1,2,3,4,5,6,8,10,12,15,20,30,40,60,80"
KEYS = ("n", "success_5deg", "success_5deg_ci95", "success_5deg_asymmetric", "median_rot_err_deg",
        "valid_rate", "constant_answer_success_5deg")  # fmt: skip


def margin_rows(protocol: str, estimator: str, margins: list[float], occlusions, seed: int,
                jobs: int, cache_dir: str | None) -> tuple[list[dict], dict]:  # fmt: skip
    """One record per (occlusion, margin) on ``protocol``, and the run's stats."""
    spec = sweep(protocol, [estimator], occlusions, seed=seed)
    run = sweep_predict_param(spec, PARAM, margins, LocalRunner(jobs), cache_dir)
    value_of = {with_param(estimator, PARAM, m): m for m in margins}
    rows = [
        {"protocol": protocol, "occlusion": r["occlusion"], "keep_margin": value_of[r["estimator"]],
         "estimator": r["estimator"], **{k: r[k] for k in KEYS}}
        for r in aggregate(run["trials"])
    ]  # fmt: skip
    return sorted(rows, key=lambda r: (r["occlusion"], r["keep_margin"])), run["stats"]


def format_table(rows: list[dict]) -> str:
    cells = list(dict.fromkeys((r["protocol"], r["occlusion"]) for r in rows))
    head = f"{'keep_margin px²':>16}" + "".join(f"{f'{p} {100 * o:.0f}%':>22}" for p, o in cells)
    lines = [head]
    for m in sorted({r["keep_margin"] for r in rows}):
        by = {(r["protocol"], r["occlusion"]): r for r in rows if r["keep_margin"] == m}
        lines.append(f"{m:>16g}" + "".join(f"{100 * by[c]['success_5deg']:>22.1f}" for c in cells))
    chance = {c: next(r for r in rows if (r["protocol"], r["occlusion"]) == c) for c in cells}
    lines.append(f"{'image-blind':>16}" + "".join(
        f"{100 * chance[c]['constant_answer_success_5deg']:>22.1f}" for c in cells))  # fmt: skip
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--estimator", default=R, help="a spec whose refiner is PnPRefiner")
    ap.add_argument("--protocols", default="top-resting,tilted,side-turntable")
    ap.add_argument("--occlusion", default="0,50")
    ap.add_argument("--margins", default=MARGINS, help="comma-separated px² values")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--cache-dir", default=None)
    ap.add_argument("--json", default=None, help="default results/keep_margin_seed{SEED}.json")
    ap.add_argument("--png", default=None, help="default: the JSON path with .png")
    ap.add_argument(
        "--replot",
        default=None,
        metavar="JSON",
        help="redraw the PNG of a JSON this script wrote, running nothing",
    )
    args = ap.parse_args(argv)
    if args.replot:
        d = json.loads(Path(args.replot).read_text())
        png = Path(args.png) if args.png else Path(args.replot).with_suffix(".png")
        plot(d["results"], d["seed"], d["estimator"], png)
        print(f"wrote {png}")
        return 0
    try:
        estimator = str(EstimatorSpec.parse(args.estimator))
        occlusions = parse_occlusions(args.occlusion)
        margins = [float(m) for m in args.margins.split(",") if m.strip()]
    except ValueError as exc:
        ap.error(str(exc))
    if not margins or any(not 0 <= m < float("inf") for m in margins):
        ap.error(f"--margins must be finite values >= 0 px², got {args.margins!r}")
    protocols = [p for p in args.protocols.split(",") if p]
    unknown = sorted(set(protocols) - set(protocol_names()))
    if unknown:
        ap.error(f"unknown protocols {unknown}; known: {', '.join(protocol_names())}")
    json_path = Path(args.json or RESULTS / f"keep_margin_seed{args.seed}.json")
    rows, stats = [], {}
    for protocol in protocols:
        try:
            got, stats[protocol] = margin_rows(protocol, estimator, margins, occlusions,
                                               args.seed, args.jobs, args.cache_dir)  # fmt: skip
        except ValueError as exc:  # e.g. an estimator without that parameter
            ap.error(str(exc))
        rows += got
        print(f"{protocol}: {stats[protocol]}", flush=True)
    print(format_table(rows))
    atomic_write_json(json_path, {
        "estimator": estimator, "parameter": PARAM, "margins": margins, "seed": args.seed,
        "protocols": protocols, "occlusions": list(occlusions), "results": rows,
        "stats": stats, "machine": {"platform": platform.platform(),
                                    "python": sys.version.split()[0], "cpus": os.cpu_count(),
                                    "jobs": args.jobs},
    })  # fmt: skip
    png = Path(args.png) if args.png else json_path.with_suffix(".png")
    plot(rows, args.seed, estimator, png)
    print(f"wrote {json_path} / {png}")
    return 0


def plot(rows: list[dict], seed: int, estimator: str, png: Path) -> None:
    curves: dict[str, list[dict]] = {}
    for r in rows:
        label = f"{r['protocol']}, {100 * r['occlusion']:.0f} % occlusion"
        curves.setdefault(label, []).append({"value": r["keep_margin"], **r})
    default = PnPRefiner().keep_margin
    plot_success_vs_parameter(curves, f"{PARAM} (px²)", png,
                              f"seed {seed}, 11 objects: {estimator}", default)  # fmt: skip


if __name__ == "__main__":
    raise SystemExit(main())
