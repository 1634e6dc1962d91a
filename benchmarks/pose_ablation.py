"""The seed's Fig. 3: success@5° against occlusion for every registered pose estimator.

For each protocol, every registered estimator (or ``--estimators``) is fitted per object on the
protocol's training views and scored on its held-out views at each occlusion level, through
:func:`scorbot_gym.experiments.ablate` (the code behind ``scorbot-gym pose ablate``). Each
protocol's sweep, with the chance level, the asymmetric-only figures, the stage-ablation table
and the issue's targets (met or not), is stored as the config ``<protocol>`` (``--config NAME``:
``<protocol>_NAME``) of ``--out`` (default: a new
``runs/pose_ablation-<time>/pose_ablation.json.gz``; the committed record is ``--out
benchmarks/results/pose_ablation.json.gz --overwrite``; gzip-compressed: it keeps every view's
error), the file's other configs left as they were. The figure ``pose_ablation.png`` shows one
config, ``--figure-config`` (the headline selection on ``side-turntable``), redrawn when that
config is written. Trials are cached, so an interrupted run resumes. Threads are pinned to one
per worker, so ``median_ms`` is a single-core time.

    python benchmarks/pose_ablation.py                      # full: 4 protocols, 0:95:5, catalogue
    python benchmarks/pose_ablation.py --protocols side-turntable --occlusion 0:90:10 \\
        --objects banana,box,foam_brick --test-views 10 --jobs 2   # a reduced run
    python benchmarks/pose_ablation.py --protocols clutter --jobs 16   # real occluders, measured
    python benchmarks/pose_ablation.py --protocols side-turntable --occlusion 0,50 \\
        --estimators manifold --perturbations "none;lighting=0.5;noise_sigma=8"  # robustness
    python benchmarks/pose_ablation.py --config select --estimators "..." --paired "select(...)"

With ``--perturbations`` each protocol is run once per perturbation (test views only; the
models are the unperturbed ones, from the model cache) and one combined record is stored as
the config ``<protocol>_perturbations`` instead.
``--replot JSON`` only redraws a figure from a sweep JSON (a result file: its
``--figure-config``; a single sweep, as ``scorbot-gym pose ablate --json`` writes: itself).
``--paired ESTIMATOR`` compares that estimator view by view with every other one of the sweep
(``paired`` in the JSON and printed); with ``--replot`` it is computed from the drawn record's
``view_errors`` and added to it.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"
os.environ.setdefault("MUJOCO_GL", "egl")

import argparse  # noqa: E402
import io  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import textwrap  # noqa: E402
from pathlib import Path  # noqa: E402

from pose.fileio import (  # noqa: E402
    CONFIGS,
    atomic_write_bytes,
    read_json,
    write_result,
)
from pose.registry import estimator_names  # noqa: E402
from scorbot_gym.data.perturbations import Perturbation  # noqa: E402
from scorbot_gym.data.protocols import get_protocol  # noqa: E402
from scorbot_gym.experiments import LocalRunner, RayRunner, SweepSpec, ablate, write_report  # noqa: E402
from scorbot_gym.experiments.aggregate import (  # noqa: E402
    format_paired,
    format_results,
    paired_differences,
    report_tables,
)
from scorbot_gym.experiments.spec import (  # noqa: E402
    EstimatorSpec,
    parse_occlusions,
    split_estimators,
)

RESULT = Path(__file__).resolve().parent / "results" / "pose_ablation.json.gz"
#: the config the figure shows: the headline per-object selection on ``side-turntable``
FIGURE_CONFIG = "side-turntable_select"
PROTOCOLS = ("side-turntable", "top-resting", "tilted", "sparse-headings")
# The targets: (protocol, occlusion, figure, minimum), checked for every composition
# of the pose-manifold estimator in the sweep (``manifold`` and its ``manifold-*`` variants).
# "coarse" is the manifold's pure-regressor answer (before refinement), recorded by the same run.
TARGETS = (
    ("side-turntable", 0.0, "success_5deg", 0.90),
    ("side-turntable", 0.5, "success_5deg", 0.60),
    ("tilted", 0.0, "success_5deg", 0.80),
    ("sparse-headings", 0.0, "coarse_success_5deg", 0.80),
)


def targets_for(protocol: str, results: list[dict]) -> list[dict]:
    cell = {(r["estimator"], r["occlusion"]): r for r in results}
    names = sorted({r["estimator"] for r in results if r["estimator"].startswith("manifold")})
    out = []
    for est in names or ["manifold"]:
        for p, occ, figure, minimum in TARGETS:
            if p != protocol:
                continue
            got = cell.get((est, occ), {}).get(figure)
            out.append({"estimator": est, "occlusion": occ, "figure": figure, "minimum": minimum,
                        "value": got, "met": None if got is None else got >= minimum})  # fmt: skip
    return out


def _cell_key(record: dict) -> tuple:
    return record["perturbation"], record["occlusion"], record["estimator"]


def perturbation_sweep(
    specs: list[SweepSpec], labels: list[str], runner, cache_dir, out: Path, config: str,
    png: Path | None,
):  # fmt: skip
    """One protocol under several perturbations: combined records stored as ``config`` of
    ``out``, and (given ``png``) success@5° per perturbation and occlusion as grouped bars, one
    panel per estimator."""
    rows, chance, stats, machine = [], {}, {}, None
    for spec, label in zip(specs, labels, strict=True):
        report = ablate(spec, runner, cache_dir)
        rows += [{**r, "perturbation": label} for r in report["results"]]
        chance[label] = report["chance"]
        stats[label], machine = report.get("stats"), report.get("machine")
        print(f"\n== {spec.protocol}, perturbation {label}")
        print(format_results(report["results"], report["chance"]))
    write_result(
        out,
        {"spec": {**specs[0].to_dict(), "perturbation": None}, "perturbations": labels,
         "results": rows, "chance": chance, "stats": stats, "machine": machine},
        config,
    )  # fmt: skip
    print(f"wrote {out} (config {config!r})")
    if png is None:
        return
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    levels = sorted({r["occlusion"] for r in rows})
    estimators = specs[0].estimators
    fig, axes = plt.subplots(
        1, len(estimators), figsize=(1 + 4.5 * len(estimators), 4.5), dpi=120, sharey=True,
        squeeze=False,
    )  # fmt: skip
    width = 0.8 / max(len(levels), 1)
    for ax, est in zip(axes[0], estimators, strict=True):
        for j, occ in enumerate(levels):
            for i, label in enumerate(labels):
                key = (label, occ, est)
                for r in (r for r in rows if _cell_key(r) == key):
                    lo, hi = r["success_5deg_ci95"]
                    y = 100 * (r["success_5deg"] or 0.0)
                    ax.bar(i + j * width, y, width, color=f"C{j}",
                           yerr=[[y - 100 * lo], [100 * hi - y]], capsize=2,
                           label=f"{100 * occ:.0f} % occlusion" if i == 0 else None)  # fmt: skip
        blind = [c["value"] for c in chance[labels[0]].get("success_5deg", [])]
        if blind:  # the constant answer does not look at the image: one line for every bar
            ax.axhline(100 * blind[0], color="grey", ls=":", lw=1, label="image-blind")
        ax.set_xticks([i + width * (len(levels) - 1) / 2 for i in range(len(labels))])
        ax.set_xticklabels(labels, rotation=15, ha="right", fontsize=7)
        ax.set_title("\n".join(textwrap.wrap(est, 55)), fontsize=6)
    axes[0][0].set_ylabel("success @ 5° (%)")
    axes[0][0].legend(fontsize=7)
    fig.suptitle(f"{specs[0].protocol} under perturbations", fontsize=9)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    atomic_write_bytes(png, buf.getvalue())
    print(f"wrote {png}")


def replot(json_path: Path, paired: str | None = None, figure_config: str = FIGURE_CONFIG) -> None:
    """Redraw a sweep's PNG from its JSON (the figure is a function of the file alone): of a
    result file, its ``figure_config``; of a single sweep's record, the record. With ``paired``,
    also compare that estimator view by view with the others, from the record's
    ``view_errors``, and add the rows to it as ``paired`` (nothing else in the file changes)."""
    try:
        data = read_json(json_path)
        config = figure_config if CONFIGS in data and "spec" not in data else None
        report = data if config is None else data[CONFIGS][figure_config]
        spec = report["spec"]
        results, chance = report["results"], report["chance"]
    except (OSError, EOFError, ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"{json_path}: not a readable sweep JSON ({exc})") from exc
    if "perturbations" in report:
        raise ValueError(f"{json_path}: a perturbation sweep; rerun it to redraw its bars")
    if paired is not None:
        if "view_errors" not in report:
            raise ValueError(f"{json_path} has no view_errors (written before sweeps kept them)")
        report["paired"] = paired_differences(report["view_errors"], paired)
        print(format_paired(report["paired"]))
        write_result(json_path, {k: v for k, v in report.items() if k != CONFIGS}, config)
    write_report({"spec": spec, "results": results, "chance": chance}, None,
                 png_path(json_path))  # fmt: skip


def png_path(json_path: Path) -> Path:
    """The PNG beside a sweep record: ``x.json.gz`` and ``x.json`` both draw ``x.png``."""
    name = json_path.name.removesuffix(".gz").removesuffix(".json")
    return json_path.with_name(f"{name}.png")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--protocols", default=",".join(PROTOCOLS))
    ap.add_argument("--estimators", default=None, help="default: every registered estimator")
    ap.add_argument(
        "--occlusion", default=None,
        help="percent levels (default: each protocol's own, 0:95:5; clutter: its bins 0:90:10)",
    )  # fmt: skip
    ap.add_argument("--objects", default=None, help="comma-separated (default: the catalogue)")
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=240)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--test-views", type=int, default=None,
                    help="first N held-out poses per object (clutter: N scenes, whose views "
                         "fall into the bins; default: the protocol's all)")  # fmt: skip
    ap.add_argument("--train-stride", type=int, default=1)
    ap.add_argument("--perturb", default=None, help="e.g. lighting=0.3,noise_sigma=4")
    ap.add_argument(
        "--perturbations", default=None,
        help='";"-separated perturbations, "none" for the unperturbed views (one combined file)',
    )  # fmt: skip
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--ray", nargs="?", const="local", default=None, metavar="ADDRESS")
    ap.add_argument("--cache-dir", default=None)
    ap.add_argument(
        "--out",
        type=Path,
        default=None,
        help="the result file (default: runs/pose_ablation-<time>/pose_ablation.json.gz; an "
        "existing file is refused without --overwrite)",
    )
    ap.add_argument("--overwrite", action="store_true", help="add to or replace an existing --out")
    ap.add_argument("--config", default="",
                    help="store each protocol's sweep as the config <protocol>_CONFIG "
                         "(default: <protocol>)")  # fmt: skip
    ap.add_argument(
        "--figure-config",
        default=FIGURE_CONFIG,
        help="the config the figure beside --out shows (default: %(default)s)",
    )
    ap.add_argument("--replot", nargs="+", default=None, metavar="JSON",
                    help="only redraw each sweep JSON's PNG beside it (no sweep runs)")  # fmt: skip
    ap.add_argument("--paired", default=None, metavar="ESTIMATOR",
                    help="compare this estimator view by view with every other one (McNemar); "
                         "with --replot, from each JSON's view_errors")  # fmt: skip
    args = ap.parse_args(argv)
    paired = None
    if args.paired:
        try:
            paired = str(EstimatorSpec.parse(args.paired))
        except ValueError as exc:
            ap.error(str(exc))
    if args.replot:
        for path in map(Path, args.replot):
            try:
                replot(path, paired, args.figure_config)
            except ValueError as exc:
                ap.error(str(exc))
            print(f"wrote {png_path(path)}")
        return 0

    try:  # every argument checked before anything runs
        if args.estimators:
            estimators = split_estimators(args.estimators)
        else:  # every registered estimator (the manifold's coarse path comes with it)
            estimators = list(estimator_names())
        objects = tuple(o for o in (args.objects or "").split(",") if o)
        pairs = Perturbation.parse_list(args.perturbations)
        labels = [label for label, _ in pairs]
        perturbations = [p for _, p in pairs] or [Perturbation.parse(args.perturb)]
        given = parse_occlusions(args.occlusion) if args.occlusion else None
        if paired is not None and paired not in [str(EstimatorSpec.parse(e)) for e in estimators]:
            raise ValueError(f"--paired {paired!r} is not among --estimators")
        if paired is not None and labels:
            raise ValueError("--paired compares estimators of one sweep; not with --perturbations")
        plan = [
            (protocol, [
                SweepSpec(protocol, tuple(estimators),
                          given or get_protocol(protocol).occlusions, objects, args.seed,
                          args.width, args.height, args.test_views, args.train_stride, p)
                for p in perturbations
            ])
            for protocol in args.protocols.split(",")
        ]  # fmt: skip
    except ValueError as exc:
        ap.error(str(exc))
    from scorbot_gym.experiments.outputs import Outputs

    suffix = f"_{args.config}" if args.config else ""
    configs = [f"{pr}_perturbations{suffix}" if labels else f"{pr}{suffix}" for pr, _ in plan]
    drawn = [".png"] if args.figure_config in configs else []
    try:  # before any work: an existing file is not replaced unless asked
        args.out = Outputs("pose_ablation", args.overwrite).path(
            args.out, "pose_ablation.json.gz", companions=drawn
        )
    except ValueError as exc:
        ap.error(str(exc))
    if args.ray is not None:
        runner = RayRunner(None if args.ray == "local" else args.ray, num_cpus=args.jobs)
    else:
        runner = LocalRunner(args.jobs)
    for protocol, specs in plan:
        if labels:
            config = f"{protocol}_perturbations{suffix}"
            png = png_path(args.out) if config == args.figure_config else None
            perturbation_sweep(specs, labels, runner, args.cache_dir, args.out, config, png)
            continue
        spec = specs[0]
        report = ablate(spec, runner, args.cache_dir)
        report["targets"] = targets_for(protocol, report["results"])
        report["machine"] = {"platform": platform.platform(), "python": sys.version.split()[0],
                             "cpus": os.cpu_count(), "jobs": args.jobs}  # fmt: skip
        if paired is not None:
            report["paired"] = paired_differences(report["view_errors"], paired)
        config = f"{protocol}{suffix}"
        write_result(args.out, {k: v for k, v in report.items() if k != "trials"}, config)
        if config == args.figure_config:
            write_report(report, None, png_path(args.out))
        print(f"\n== {protocol}\n" + format_results(report["results"], report["chance"]))
        for table in report_tables(report):
            print(table)
        for t in report["targets"]:
            print(f"target {t}")
        for f in report["fit_errors"]:
            print(f"not fitted: {f['estimator']} on {f['object']}: {f['error']}")
        print(f"stats {report['stats']}\nwrote {args.out} (config {config!r})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
