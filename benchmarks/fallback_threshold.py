"""Choose ``fallback(min_confidence=...)`` on one seed's trials.

Sweeps the main estimator and the fallback (``chance`` by default) on the given protocols and
occlusion levels under ``--seed`` (through :func:`scorbot_gym.experiments.run_sweep`, so trials
are cached and shared with ``pose_ablation.py``), then scores the gated composition for every
threshold from the per-view confidences (:func:`scorbot_gym.experiments.gate.gate_curve`).
Writes ``benchmarks/results/fallback_threshold_seed<seed>.json``: per cell the main, fallback
and gated success@5°, each threshold's mean over the cells and the best one. Measure the chosen
threshold on another seed with ``pose_ablation.py``.

    python benchmarks/fallback_threshold.py --seed 1
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"
os.environ.setdefault("MUJOCO_GL", "egl")

import argparse  # noqa: E402
from pathlib import Path  # noqa: E402

from pose.fileio import atomic_write_json  # noqa: E402
from scorbot_gym.experiments import LocalRunner, run_sweep, sweep  # noqa: E402
from scorbot_gym.experiments.gate import best_threshold, gate_curve  # noqa: E402
from scorbot_gym.experiments.spec import EstimatorSpec  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
MAIN = "manifold-pnp(keypoints__upscale=2, matcher__min_inliers=6)"
PROTOCOLS = "top-resting,side-turntable,tilted,sparse-headings,overview,cross-camera"
THRESHOLDS = (0.0, 0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.35, 0.4, 0.5)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--main", default=MAIN, help="estimator spec to gate")
    ap.add_argument("--fallback", default="chance", help="estimator spec answering below it")
    ap.add_argument("--protocols", default=PROTOCOLS)
    ap.add_argument("--occlusion", default="0,25,50,75")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    try:
        main_spec, back_spec = (str(EstimatorSpec.parse(s)) for s in (args.main, args.fallback))
        specs = [  # every protocol and occlusion level checked before anything runs
            sweep(protocol, [main_spec, back_spec], args.occlusion, seed=args.seed)
            for protocol in args.protocols.split(",")
        ]
    except ValueError as err:
        ap.error(str(err))
    trials, stats = [], []
    for spec in specs:
        protocol = spec.protocol
        run = run_sweep(spec, LocalRunner(jobs=args.jobs))
        trials += run["trials"]
        stats.append({"protocol": protocol, **run["stats"]})
    curve = gate_curve(trials, main_spec, back_spec, THRESHOLDS)
    best, means = best_threshold(curve)
    for c in curve:
        gated = " ".join(f"{t:g}:{100 * v:.1f}" for t, v in c["gated"].items())
        print(f"{c['protocol']:16s} {c['occlusion']:.2f} main {100 * c['main']:5.1f} "
              f"fallback {100 * c['fallback']:5.1f} | {gated}")  # fmt: skip
    print("mean over cells:", " ".join(f"{t:g}:{100 * v:.2f}" for t, v in means.items()))
    print(f"best min_confidence: {best:g}")
    out = args.out or RESULTS / f"fallback_threshold_seed{args.seed}.json"
    atomic_write_json(
        out,
        {
            "main": main_spec,
            "fallback": back_spec,
            "seed": args.seed,
            "thresholds": list(THRESHOLDS),
            "cells": curve,
            "mean_over_cells": {str(t): v for t, v in means.items()},
            "best_min_confidence": best,
            "stats": stats,
        },
    )
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
