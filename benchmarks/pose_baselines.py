"""Pose baselines against the manifold estimator, on named protocols and occlusion levels.

Every estimator registered in :mod:`pose.registry` (the baselines of :mod:`pose.baselines`
and ``manifold``) is fitted per object on the protocol's training views (rendered with depth,
which the PnP baselines need) and scored on its held-out views at each occlusion level:
symmetry-aware rotation error, success@5deg, position error (``coarse_*``: the estimator's
``rotation_coarse``, the manifold's regressor before refinement, a baseline's unrefined
answer). Figures are reported for all
objects and for the *asymmetric* ones only (no axial symmetry: a can or a ball is right about
its axis whatever the heading, which flatters image-blind answers); ``chance`` is the
image-blind level. Threads are pinned to one, so the per-view times are single-core times.

    nice -n 10 python benchmarks/pose_baselines.py            # 4 objects, 3 protocols
    python benchmarks/pose_baselines.py --quick               # 2 objects, top-resting, smoke test

Writes ``pose_baselines.json`` and ``pose_baselines.png``, by default into a new
``runs/pose_baselines-<time>/``; the committed record is rebuilt with ``--out
benchmarks/results/pose_baselines.json --overwrite`` (an existing ``--out`` is refused without it).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"
os.environ.setdefault("MUJOCO_GL", "egl")

import argparse  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from datetime import datetime, timezone  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

cv2.setNumThreads(1)

from pose.fileio import atomic_write, atomic_write_json  # noqa: E402
from pose.metrics import rotation_error_deg, summarize, translation_error  # noqa: E402
from pose.registry import estimator_names, make_estimator  # noqa: E402
from scorbot_gym.data.protocols import describe, held_out_views, train_views  # noqa: E402
from scorbot_gym.objects import get_object  # noqa: E402

ESTIMATORS = (
    "chance", "least-squares", "pca-nn", "pca-rbf", "part-based", "n3m", "sift-pnp",
    "nearest-view", "manifold",
)  # fmt: skip
OBJECTS = ("banana", "potted_meat_can", "foam_brick", "tomato_soup_can")
PROTOCOLS = ("top-resting", "side-turntable", "tilted")


def _score(est, views, symmetry) -> dict[str, list]:
    rec: dict[str, list] = {"rot": [], "coarse": [], "trans": [], "ms": []}
    for lv in views:
        e = est.predict(lv.view)
        R = lv.camera_from_object[:3, :3]
        rec["rot"].append(rotation_error_deg(e.rotation, R, symmetry))
        rec["coarse"].append(rotation_error_deg(e.rotation_coarse, R, symmetry))
        rec["trans"].append(translation_error(e.translation, lv.camera_from_object[:3, 3]))
        rec["ms"].append(e.timings_ms["total"])
    return rec


def _summary(rec: dict[str, list]) -> dict:
    s = summarize(rec["rot"], rec["trans"], rec["coarse"])
    s["median_ms"] = float(np.median(rec["ms"]))
    # NaN (no valid estimate at all) is written as null: strict JSON
    return {k: (round(v, 4) if np.isfinite(v) else None) if isinstance(v, float) else v
            for k, v in s.items()}  # fmt: skip


def _fmt(v, spec: str) -> str:
    return format(v, spec) if v is not None else "-"


def run(protocol: str, objects, estimators, occlusions, width: int, height: int) -> dict:
    """Per estimator: fit seconds per object and, per occlusion level, summaries for every
    object, ``all`` objects pooled and the ``asymmetric`` ones pooled."""
    out: dict = {name: {"fit_s": {}, "levels": {}} for name in estimators}
    for obj in objects:
        spec = get_object(obj)
        cams = train_views(protocol, obj, width=width, height=height, depth=True)
        views = [lv.view for vs in cams.values() for lv in vs]
        poses = np.array([lv.camera_from_object for vs in cams.values() for lv in vs])
        tests = {occ: held_out_views(protocol, obj, occ, width=width, height=height)
                 for occ in occlusions}  # fmt: skip
        for name in estimators:
            t0 = time.perf_counter()
            est = make_estimator(name).fit(views, poses)
            out[name]["fit_s"][obj] = round(time.perf_counter() - t0, 2)
            for occ, tv in tests.items():
                rec = _score(est, tv, spec.symmetry)
                level = out[name]["levels"].setdefault(f"{round(100 * occ)}", {"_rec": {}})
                level[obj] = _summary(rec)
                level["_rec"][obj] = (rec, spec.symmetry.kind != "axial")
            print(f"{protocol:15s} {obj:16s} {name:14s} fit {out[name]['fit_s'][obj]:6.1f} s  "
                  + "  ".join(f"{k}%: {v[obj]['success_5deg']:.2f}"
                              for k, v in out[name]["levels"].items()), flush=True)  # fmt: skip
    for name in estimators:
        for level in out[name]["levels"].values():
            recs = level.pop("_rec")
            for key, keep in (("all", lambda a: True), ("asymmetric", lambda a: a)):
                chosen = [r for r, asym in recs.values() if keep(asym)]
                if chosen:
                    level[key] = _summary({k: sum((r[k] for r in chosen), []) for k in chosen[0]})
    return out


def plot(results: dict, path: Path, key: str) -> None:
    """success@5deg per estimator, one panel per protocol, one bar per occlusion level; the
    dashed line is the chance level at 0 % occlusion."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    protos = list(results)
    fig, axes = plt.subplots(1, len(protos), figsize=(5.5 * len(protos), 4.2), squeeze=False)
    for ax, proto in zip(axes[0], protos, strict=True):
        names = list(results[proto])
        levels = list(results[proto][names[0]]["levels"])
        width = 0.8 / len(levels)
        for j, lev in enumerate(levels):
            vals = [results[proto][n]["levels"][lev][key]["success_5deg"] for n in names]
            ax.bar(np.arange(len(names)) + (j - (len(levels) - 1) / 2) * width, vals, width,
                   label=f"{lev} % occluded")  # fmt: skip
        if "chance" in names:
            chance = results[proto]["chance"]["levels"][levels[0]][key]["success_5deg"]
            ax.axhline(chance, color="k", ls="--", lw=1, label="chance")
        ax.set_xticks(range(len(names)), names, rotation=60, ha="right", fontsize=8)
        ax.set_ylim(0, 1.05)
        ax.set_title(f"{proto} ({key} objects)", fontsize=10)
        ax.set_ylabel("success @ 5 deg")
    axes[0][0].legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    atomic_write(path, lambda f: fig.savefig(f, format="png", dpi=110))
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--objects", nargs="*", default=list(OBJECTS))
    ap.add_argument("--protocols", nargs="*", default=list(PROTOCOLS))
    ap.add_argument("--estimators", nargs="*", default=list(ESTIMATORS),
                    help=f"registered names: {', '.join(estimator_names())}")  # fmt: skip
    ap.add_argument("--occlusion", default="0,50", help="percent, comma-separated")
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=240)
    ap.add_argument("--quick", action="store_true")
    from scorbot_gym.experiments.outputs import Outputs, add_overwrite_option

    ap.add_argument(
        "--out",
        type=Path,
        default=None,
        help="where to write (default: runs/pose_baselines-<time>/pose_baselines.json; an existing "
        "file is refused without --overwrite)",
    )
    add_overwrite_option(ap)
    args = ap.parse_args(argv)
    try:  # before any work: an existing file is not replaced unless asked
        args.out = Outputs("pose_baselines", args.overwrite).path(
            args.out, "pose_baselines.json", "--out", companions=[".png"]
        )
    except ValueError as exc:
        ap.error(str(exc))
    if args.quick:
        args.objects, args.protocols = args.objects[:2], args.protocols[:1]
    unknown = sorted(set(args.estimators) - set(estimator_names()))
    if unknown:
        ap.error(f"unknown estimators {unknown}; registered: {', '.join(estimator_names())}")
    occlusions = [float(v) / 100 for v in args.occlusion.split(",")]

    t0 = time.perf_counter()
    results = {p: run(p, args.objects, args.estimators, occlusions, args.width, args.height)
               for p in args.protocols}  # fmt: skip
    report = {
        "benchmark": "pose_baselines",
        "date_utc": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "setup": {
            "objects": args.objects,
            "asymmetric_objects": [
                o for o in args.objects if get_object(o).symmetry.kind != "axial"
            ],  # fmt: skip
            "protocols": describe(args.protocols),
            "estimators": args.estimators,
            "occlusions": occlusions,
            "image_size": [args.width, args.height],
            "success": "symmetry-aware geodesic rotation error < 5 deg; invalid = failure",
            "threads": 1,
            "wall_s": None,
        },
        "results": results,
        "environment": {
            "python": sys.version.split()[0],
            "opencv": cv2.__version__,
            "numpy": np.__version__,
            "machine": platform.machine(),
        },
    }
    report["setup"]["wall_s"] = round(time.perf_counter() - t0, 1)
    atomic_write_json(args.out, report)
    png = args.out.with_suffix(".png")
    plot(results, png, "asymmetric" if report["setup"]["asymmetric_objects"] else "all")
    for proto, res in results.items():
        print(f"\n{proto}: success@5deg all / asymmetric objects, median rot err (deg), ms")
        for name, r in res.items():
            cells = []
            for lev, s in r["levels"].items():
                a, asym = s["all"], s.get("asymmetric", {}).get("success_5deg")
                cells.append(
                    f"{lev:>3}%: {a['success_5deg']:.2f} / {_fmt(asym, '.2f')} "
                    f"{_fmt(a['median_rot_err_deg'], '7.2f')} {a['median_ms']:6.1f}"
                )
            print(f"  {name:14s} " + "   ".join(cells))  # fmt: skip
    print(f"\nwrote {args.out} and {png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
