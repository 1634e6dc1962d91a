"""Which candidate a ``select(...)`` estimator chose for each object, with the scores.

The cross-validated scores of every candidate: the table behind the README's *Choosing per
object* section.

A sweep's JSON (``selections``) holds the same rows for the protocols it ran; this script
collects them across protocols without running a trial: it reads the fitted selections from
the sweep's model cache (the ones ``pose_ablation.py`` fitted with the same arguments),
fitting and caching them where the cache has none.

    python benchmarks/selection_choices.py --estimator "select(estimators=(...))" \
        --protocols overview,top-resting
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

from pose.fileio import atomic_write_json  # noqa: E402
from scorbot_gym.data.protocols import protocol_names  # noqa: E402
from scorbot_gym.experiments import sweep  # noqa: E402
from scorbot_gym.experiments.runners import make_jobs  # noqa: E402
from scorbot_gym.experiments.spec import EstimatorSpec  # noqa: E402
from scorbot_gym.experiments.trial import (  # noqa: E402
    default_cache_dir,
    fitted_model,
    selection_record,
)
from scorbot_gym.objects import get_object  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"


def choices(protocol: str, estimator: str, seed: int, cache_dir: str) -> list[dict]:
    spec = sweep(protocol, [estimator], "0", seed=seed)
    return [
        {"protocol": protocol, "object": job.object_name,
         "symmetry": get_object(job.object_name).symmetry.kind,
         # the sweep's cached fit, or fitted and cached here
         **selection_record(fitted_model(job))}
        for job in make_jobs(spec, cache_dir)
    ]  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--estimator", required=True, help="a select(...) spec")
    ap.add_argument("--protocols", default=",".join(protocol_names()))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cache-dir", default=None)
    ap.add_argument("--json", default=str(RESULTS / "selection_choices.json"))
    args = ap.parse_args(argv)
    try:
        spec = EstimatorSpec.parse(args.estimator)
    except ValueError as exc:
        ap.error(str(exc))
    if spec.name != "select":
        ap.error(f"--estimator must be a select(...) spec, got {spec.name!r}")
    protocols = [p for p in args.protocols.split(",") if p]
    unknown = sorted(set(protocols) - set(protocol_names()))
    if unknown:
        ap.error(f"unknown protocols {unknown}; known: {', '.join(protocol_names())}")
    cache = str(args.cache_dir or default_cache_dir())
    rows = [r for p in protocols for r in choices(p, str(spec), args.seed, cache)]
    for r in rows:
        print(f"{r['protocol']:16s} {r['object']:16s} {r['symmetry']:9s} {r['selected'][:70]}")
    atomic_write_json(Path(args.json), {"estimator": str(spec), "seed": args.seed,
                                        "choices": rows})  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
