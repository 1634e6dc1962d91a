"""The seed's Fig. 3: success@5° against occlusion for every registered pose estimator.

For each protocol, every registered estimator (or ``--estimators``) is fitted per object on the
protocol's training views and scored on its held-out views at each occlusion level, through
:func:`scorbot_gym.experiments.ablate` (the code behind ``scorbot-gym pose ablate``). Writes
``benchmarks/results/pose_ablation_<protocol>.json`` and ``.png`` per protocol, with the
chance level, the asymmetric-only figures, the stage-ablation table and the issue's targets
(met or not). Trials are cached, so an interrupted run resumes. Threads are pinned to one per
worker, so ``median_ms`` is a single-core time.

    python benchmarks/pose_ablation.py                      # full: 4 protocols, 0:95:5, catalogue
    python benchmarks/pose_ablation.py --protocols side-turntable --occlusion 0:90:10 \\
        --objects banana,box,foam_brick --test-views 10 --jobs 2   # a reduced run
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"
os.environ.setdefault("MUJOCO_GL", "egl")

import argparse  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

from pose.registry import estimator_names  # noqa: E402
from scorbot_gym.data.perturbations import Perturbation  # noqa: E402
from scorbot_gym.experiments import LocalRunner, RayRunner, SweepSpec, ablate, write_report  # noqa: E402
from scorbot_gym.experiments.aggregate import format_results, format_stage_ablation  # noqa: E402
from scorbot_gym.experiments.spec import parse_occlusions, split_estimators  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
PROTOCOLS = ("side-turntable", "top-resting", "tilted", "sparse-headings")
# The targets: (protocol, estimator, occlusion, figure, minimum). "coarse" is the
# manifold's pure-regressor answer (before refinement), recorded by the same run.
TARGETS = (
    ("side-turntable", "manifold", 0.0, "success_5deg", 0.90),
    ("side-turntable", "manifold", 0.5, "success_5deg", 0.60),
    ("tilted", "manifold", 0.0, "success_5deg", 0.80),
    ("sparse-headings", "manifold", 0.0, "coarse_success_5deg", 0.80),
)


def targets_for(protocol: str, results: list[dict]) -> list[dict]:
    cell = {(r["estimator"], r["occlusion"]): r for r in results}
    out = []
    for p, est, occ, figure, minimum in TARGETS:
        if p != protocol:
            continue
        got = cell.get((est, occ), {}).get(figure)
        out.append({"estimator": est, "occlusion": occ, "figure": figure, "minimum": minimum,
                    "value": got, "met": None if got is None else got >= minimum})  # fmt: skip
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--protocols", default=",".join(PROTOCOLS))
    ap.add_argument("--estimators", default=None, help="default: every registered estimator")
    ap.add_argument("--occlusion", default="0:95:5")
    ap.add_argument("--objects", default=None, help="comma-separated (default: the catalogue)")
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=240)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--test-views", type=int, default=None)
    ap.add_argument("--train-stride", type=int, default=1)
    ap.add_argument("--perturb", default=None, help="e.g. lighting=0.3,noise_sigma=4")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--ray", nargs="?", const="local", default=None, metavar="ADDRESS")
    ap.add_argument("--cache-dir", default=None)
    ap.add_argument("--out-dir", default=str(RESULTS))
    ap.add_argument("--suffix", default="", help="appended to the result file names")
    args = ap.parse_args(argv)

    if args.estimators:
        estimators = split_estimators(args.estimators)
    else:  # every registered estimator (the manifold's coarse path comes with it)
        estimators = list(estimator_names())
    objects = tuple(o for o in (args.objects or "").split(",") if o)
    if args.ray is not None:
        runner = RayRunner(None if args.ray == "local" else args.ray, num_cpus=args.jobs)
    else:
        runner = LocalRunner(args.jobs)
    for protocol in args.protocols.split(","):
        spec = SweepSpec(
            protocol, tuple(estimators), parse_occlusions(args.occlusion), objects, args.seed,
            args.width, args.height, args.test_views, args.train_stride,
            Perturbation.parse(args.perturb),
        )  # fmt: skip
        report = ablate(spec, runner, args.cache_dir)
        report["targets"] = targets_for(protocol, report["results"])
        report["machine"] = {"platform": platform.platform(), "python": sys.version.split()[0],
                             "cpus": os.cpu_count(), "jobs": args.jobs}  # fmt: skip
        stem = Path(args.out_dir) / f"pose_ablation_{protocol}{args.suffix}"
        write_report(report, stem.with_suffix(".json"), stem.with_suffix(".png"))
        print(f"\n== {protocol}\n" + format_results(report["results"], report["chance"]))
        table = format_stage_ablation(report["stage_ablation"])
        if table:
            print(table)
        for t in report["targets"]:
            print(f"target {t}")
        print(f"stats {report['stats']}\nwrote {stem}.json / .png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
