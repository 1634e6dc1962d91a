"""Tilted objects in the closed loop (issue 37, item 3): which default models, and the loop.

``models``: every candidate training set (:class:`~scorbot_gym.perception.training.TrainingSet`:
views and estimator composition) is trained per object on the top camera at 320x240 (candidates
that differ only in predict-time parameters of the PnP refiner share one fit) and scored on the
same held-out views: the ``tilted`` protocol's test poses (tilted 0-30 degrees out of a
resting pose, seed 1) and the ``top-resting`` protocol's (resting, seed 1). success@5deg is
symmetry-aware; ``per_tilt`` splits the tilted views by tilt. The cost per estimate is timed
afterwards in one process pinned to one core, the candidates interleaved view by view
(:mod:`scorbot_gym.experiments.latency`), so their ratio is fair on a shared machine. A
candidate trained on the whole catalogue is also stored where ``default_pose_models`` looks for
it (the same content key: same views, composition, seed and code), which spares the ``loop``
part the training.

``loop``: seeded closed-loop episodes with the target propped on the stand at each ``--tilts``
angle, the catalogue drawn, the scripted controller; arms ``oracle`` (the ceiling) and
``manifold`` (background subtraction + the default models, no privileged input): grasp success,
success@5deg of the valid estimates (pooled over every estimate of every episode;
an invalid estimate is not counted there, the valid rate is beside it), ms per estimate.

Both parts update their own section of ``benchmarks/results/tilted_in_loop.json``.

    python benchmarks/tilted_in_loop.py models [--jobs 2] [--objects box cylinder]
    python benchmarks/tilted_in_loop.py loop [--episodes 70] [--tilts 0 10 20 30] [--jobs 2]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

OUT = Path(__file__).parent / "results" / "tilted_in_loop.json"
#: what is fitted: label -> TrainingSet keyword arguments
FITS = {
    "resting/manifold": {},  # the previous default
    "resting/manifold-pnp": {"estimator": "manifold-pnp"},
    "resting+tilted/manifold": {"estimator": "manifold", "tilted_views": 216},
    "resting+tilted/manifold-pnp": {"estimator": "manifold-pnp", "tilted_views": 216},
    "resting+tilted/manifold-pnp(upscale=2)": {
        "estimator": "manifold-pnp(keypoints__upscale=2)",
        "tilted_views": 216,
    },
}
#: candidate -> (fit, predict-time parameters set on the fitted model: the PnP refiner's keep
#: test and correspondences act only in ``predict``, so one fit serves several candidates)
GLOBAL = {"refiner__correspondences": "ratio+global"}
CANDIDATES = {
    "resting/manifold": ("resting/manifold", {}),
    "resting/manifold-pnp": ("resting/manifold-pnp", {}),
    "resting/manifold-pnp(global)": ("resting/manifold-pnp", GLOBAL),
    "resting+tilted/manifold": ("resting+tilted/manifold", {}),
    "resting+tilted/manifold-pnp": ("resting+tilted/manifold-pnp", {}),
    "resting+tilted/manifold-pnp(keep30)": (
        "resting+tilted/manifold-pnp",
        {"refiner__keep_margin": 30.0},
    ),
    "resting+tilted/manifold-pnp(global)": ("resting+tilted/manifold-pnp", GLOBAL),
    "resting+tilted/manifold-pnp(global,keep30)": (
        "resting+tilted/manifold-pnp",
        {**GLOBAL, "refiner__keep_margin": 30.0},
    ),
    "resting/manifold-pnp(global,keep0)": (
        "resting/manifold-pnp",
        {**GLOBAL, "refiner__keep_margin": 0.0},
    ),
    "resting+tilted/manifold-pnp(global,keep0)": (
        "resting+tilted/manifold-pnp",
        {**GLOBAL, "refiner__keep_margin": 0.0},
    ),
    "resting+tilted/manifold-pnp(upscale=2,global)": (
        "resting+tilted/manifold-pnp(upscale=2)",
        GLOBAL,
    ),
}
DEFAULT_CANDIDATES = [c for c in CANDIDATES if "upscale" not in c]
TILT_BINS = (0.0, 10.0, 20.0, 30.0001)
TIMED_VIEWS_PER_OBJECT = 4


def training_of(candidate: str):
    """The :class:`TrainingSet` a candidate amounts to (its predict-time parameters written
    into the estimator spec): what ``default_pose_models`` would train for it."""
    from scorbot_gym.experiments.predict_params import with_param
    from scorbot_gym.perception.training import TrainingSet

    fit, predict = CANDIDATES[candidate]
    kwargs = dict(FITS[fit])
    spec = kwargs.pop("estimator", "manifold")
    for k, v in predict.items():
        spec = with_param(spec, k, v)
    return TrainingSet(estimator=spec, **kwargs)


def _evaluate_fit(fit: str, name: str, candidates: list[str]) -> dict:
    """Train one fit on one object, score each of its candidates on the held-out views (a
    worker's job)."""
    import cv2
    import numpy as np

    from pose.manifold.estimator import PoseManifoldEstimator
    from pose.metrics import rotation_error_deg
    from scorbot_gym.data.protocols import held_out_views
    from scorbot_gym.objects import get_object
    from scorbot_gym.perception.training import TrainingSet, train_object

    cv2.setNumThreads(1)
    arrays, info = train_object(name, progress=False, training=TrainingSet(**FITS[fit]))
    symmetry = get_object(name).symmetry
    tests = {p: held_out_views(p, name, 0.0) for p in ("tilted", "top-resting")}
    out = []
    for label in candidates:
        est = PoseManifoldEstimator.from_arrays(arrays).set_params(**CANDIDATES[label][1])
        rec = {"label": label, "object": name, "train": info, "arrays": est.to_arrays()}
        for protocol, views in tests.items():
            rows = []
            for lv in views:
                e = est.predict(lv.view)
                R, t = lv.camera_from_object[:3, :3], lv.camera_from_object[:3, 3]
                err = rotation_error_deg(e.rotation, R, symmetry) if e.valid else 180.0
                t_err = float(np.linalg.norm(e.translation - t)) if e.valid else 1.0
                rows.append((err, float(np.degrees(lv.sample.tilt)), t_err, bool(e.valid)))
            rec[protocol] = rows
        out.append(rec)
    return out


def _rates(rows: list) -> dict:
    import numpy as np

    from scorbot_gym.evaluation.summary import wilson_interval

    err = np.array([r[0] for r in rows])
    ok = int((err <= 5.0).sum())
    return {
        "n": len(rows),
        "success_5deg": round(ok / len(rows), 4),
        "success_5deg_ci95": [round(v, 4) for v in wilson_interval(ok, len(rows))],
        "median_rot_err_deg": round(float(np.median(err)), 3),
        "median_trans_err_cm": round(100 * float(np.median([r[2] for r in rows])), 3),
        "valid_rate": round(float(np.mean([r[3] for r in rows])), 4),
    }


def run_models(args: argparse.Namespace) -> dict:
    import numpy as np

    from pose.manifold.estimator import PoseManifoldEstimator
    from pose.model_set import PoseModelSet
    from scorbot_gym.data.protocols import held_out_views
    from scorbot_gym.experiments.latency import pin_to_one_core, summarize_latency, time_predictions
    from scorbot_gym.objects import CATALOGUE
    from scorbot_gym.perception.training import (
        IN_LOOP_TRAINING,
        default_models_path,
    )

    names = args.objects or list(CATALOGUE)
    fits = list(dict.fromkeys(CANDIDATES[c][0] for c in args.candidates))
    jobs = [
        (f, n, [c for c in args.candidates if CANDIDATES[c][0] == f]) for f in fits for n in names
    ]
    t0 = time.perf_counter()
    if args.jobs > 1:
        from scorbot_gym.experiments.workers import worker_pool

        with worker_pool(args.jobs) as pool:
            futures = [pool.submit(_evaluate_fit, *j) for j in jobs]
            done = [d for f in futures for d in f.result()]
    else:
        done = [d for j in jobs for d in _evaluate_fit(*j)]
    wall = time.perf_counter() - t0
    rows = []
    for label in args.candidates:
        mine = [d for d in done if d["label"] == label]
        tilted = [r for d in mine for r in d["tilted"]]
        per_tilt = {}
        for lo, hi in zip(TILT_BINS[:-1], TILT_BINS[1:], strict=True):
            sub = [r for r in tilted if lo <= r[1] < hi]
            per_tilt[f"{lo:g}-{min(hi, 30):g}"] = _rates(sub)["success_5deg"] if sub else None
        rows.append(
            {
                "candidate": label,
                "training": training_of(label).to_dict(),
                "tilted": _rates(tilted),
                "tilted_per_tilt_deg": per_tilt,
                "resting": _rates([r for d in mine for r in d["top-resting"]]),
                "per_object_tilted_success_5deg": {
                    d["object"]: _rates(d["tilted"])["success_5deg"] for d in mine
                },
                "train_views_per_object": int(np.median([d["train"]["views"] for d in mine])),
                "fit_s_per_object": round(float(np.median([d["train"]["fit_s"] for d in mine])), 1),
            }
        )
        if sorted(names) == sorted(CATALOGUE):  # spares default_pose_models the training
            training = training_of(label)
            path = default_models_path(training=training)
            if not path.is_file():
                ms = PoseModelSet(
                    {d["object"]: PoseManifoldEstimator.from_arrays(d["arrays"]) for d in mine},
                    meta={"camera": "top", "width": 320, "height": 240, "seed": 0,
                          "training": training.to_dict()},
                )  # fmt: skip
                path.parent.mkdir(parents=True, exist_ok=True)
                ms.save(path, meta={**ms.meta, "cache_key": path.stem.rsplit("-", 1)[-1]})
    # the cost per estimate: one pinned core, candidates interleaved on the same views
    views = []
    for n in names:
        views += [lv.view for lv in held_out_views("tilted", n, 0.0)[:TIMED_VIEWS_PER_OBJECT]]
    owners = [n for n in names for _ in range(TIMED_VIEWS_PER_OBJECT)]
    core = pin_to_one_core()
    per_view: dict[str, list] = {label: [] for label in args.candidates}
    for n in names:
        ests = {
            d["label"]: PoseManifoldEstimator.from_arrays(d["arrays"])
            for d in done
            if d["object"] == n
        }
        mine = [v for v, o in zip(views, owners, strict=True) if o == n]
        for label, ms in time_predictions(ests, mine, repeats=3).items():
            per_view[label] += list(ms)
    latency = summarize_latency(
        {k: np.array(v) for k, v in per_view.items()}, reference=args.candidates[0]
    )
    in_loop = next((c for c in args.candidates if training_of(c) == IN_LOOP_TRAINING), None)
    return {
        "objects": names,
        "test_views_per_object": {"tilted": 30, "resting": 30},
        "candidates": rows,
        "latency_one_core": {"core": core, "views": len(views), "rows": latency},
        "in_loop_default": in_loop,
        "wall_s": round(wall, 1),
        "jobs": args.jobs,
    }


def _loop_arm(
    label: str, pose: str, tilt: float, episodes: int, seed: int, objects, pose_model
) -> dict:
    import cv2

    from scorbot_gym.evaluation.rollout import RolloutConfig, run_rollout

    cv2.setNumThreads(1)
    config = RolloutConfig(
        pose=pose, tilt_deg=tilt, episodes=episodes, seed=seed, objects=objects,
        pose_model=pose_model if pose == "manifold" else None,
    )  # fmt: skip
    t0 = time.perf_counter()
    summary, _ = run_rollout(config, progress=False)
    results = summary.pop("results")
    perception = [r["perception"] for r in results if r.get("perception")]
    valid = sum(p["valid"] for p in perception)
    hits = sum(p["valid"] * (p["success_5deg"] or 0.0) for p in perception)
    if tilt > 0:
        summary["settled_tilt_deg"] = _settled_tilts(config)
    summary.update(
        label=label,
        tilt_deg=tilt,
        wall_s=round(time.perf_counter() - t0, 1),
        estimates_valid=valid,
        success_5deg_of_valid_estimates=round(hits / valid, 4) if valid else None,
    )
    return summary


def _settled_tilts(config) -> dict:
    """How far the targets of these episodes really lean once settled on the stand (the env's
    ground truth at reset, for the record): an object can slide or roll against the stand's
    lip and settle at another tilt than the stand's."""
    import numpy as np

    env = config.make_env()
    try:
        tilts = []
        for seed in range(config.seed, config.seed + config.episodes):
            _, info = env.reset(seed=seed, options=config.reset_options)
            tilts.append(info["objects"][info["target_name"]]["tilt_deg"])
    finally:
        env.close()
    t = np.array(tilts)
    return {
        "median": round(float(np.median(t)), 2),
        "min": round(float(t.min()), 2),
        "max": round(float(t.max()), 2),
        "above_30deg": int((t > 30.0).sum()),
    }


def run_loop(args: argparse.Namespace) -> dict:
    from scorbot_gym.evaluation.summary import wilson_interval
    from scorbot_gym.perception.training import default_models_path, default_pose_models

    objects = tuple(args.objects) if args.objects else None
    default_pose_models(objects=objects, progress=True)  # trained once here, not per worker
    model = str(default_models_path(objects=objects)) if objects else None
    runs = []
    for i, tilt in enumerate(args.tilts):
        for label in ("oracle", "manifold"):
            runs.append((label, label, tilt, args.episodes, args.seed + 1000 * i, objects, model))
    t0 = time.perf_counter()
    if args.jobs > 1:
        from scorbot_gym.experiments.workers import worker_pool

        with worker_pool(args.jobs) as pool:
            arms = [f.result() for f in [pool.submit(_loop_arm, *r) for r in runs]]
    else:
        arms = [_loop_arm(*r) for r in runs]
    for a in arms:
        p = a.get("perception") or {}
        print(
            f"{a['label']:>9} tilt {a['tilt_deg']:4.0f}: grasp {a['success_rate']:6.1%} "
            f"(n={a['episodes']})  ok@5deg {a['success_5deg_of_valid_estimates']}  "
            f"ms {p.get('median_estimate_ms')}",
            flush=True,
        )
    totals = {}  # over the tilted arms, and over the resting ones (tilt 0) apart
    for label in ("oracle", "manifold"):
        for kind, keep in (("tilted", lambda t: t > 0), ("resting", lambda t: t == 0)):
            mine = [a for a in arms if a["label"] == label and keep(a["tilt_deg"])]
            if not mine:
                continue
            n, ok = sum(a["episodes"] for a in mine), sum(a["successes"] for a in mine)
            valid = sum(a["estimates_valid"] for a in mine)
            hits = sum(
                a["estimates_valid"] * (a["success_5deg_of_valid_estimates"] or 0) for a in mine
            )
            totals[f"{label}_{kind}"] = {
                "episodes": n,
                "grasp_success": round(ok / n, 4),
                "grasp_success_ci95": [round(v, 4) for v in wilson_interval(ok, n)],
                "estimates_valid": valid,
                "success_5deg_of_valid_estimates": round(hits / valid, 4) if valid else None,
                "median_estimate_ms_of_arms": [
                    (a.get("perception") or {}).get("median_estimate_ms") for a in mine
                ],
            }
    return {
        "objects": list(objects) if objects else "catalogue",
        "tilts_deg": list(args.tilts),
        "episodes_per_tilt": args.episodes,
        "seed": args.seed,
        "arms": arms,
        "totals": totals,
        "targets": {"success_5deg": 0.8, "grasp_success": 0.9},
        "wall_s": round(time.perf_counter() - t0, 1),
        "jobs": args.jobs,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="part", required=True)
    m = sub.add_parser("models", help="candidate training sets on tilted and resting views")
    m.add_argument("--candidates", nargs="+", choices=list(CANDIDATES), default=DEFAULT_CANDIDATES)
    m.add_argument("--objects", nargs="+", default=None)
    m.add_argument("--jobs", type=int, default=1)
    lp = sub.add_parser("loop", help="closed-loop episodes with tilted targets")
    lp.add_argument("--episodes", type=int, default=20, help="per arm and tilt")
    lp.add_argument("--tilts", type=float, nargs="+", default=[10.0, 20.0, 30.0])
    lp.add_argument("--seed", type=int, default=7000)
    lp.add_argument("--jobs", type=int, default=1)
    lp.add_argument("--objects", nargs="+", default=None, help="default: the catalogue")
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--section", default=None, help="key of the JSON to write (default: part)")
    args = ap.parse_args(argv)
    if args.jobs < 1 or getattr(args, "episodes", 1) < 1:
        ap.error("--jobs and --episodes must be >= 1")
    if any(not 0 <= t <= 45 for t in getattr(args, "tilts", [])):
        ap.error("--tilts must be angles in [0, 45] degrees (0: resting, no stand)")

    from pose.fileio import atomic_write_json

    section = run_models(args) if args.part == "models" else run_loop(args)
    report = json.loads(args.out.read_text()) if args.out.is_file() else {}
    section["machine"] = {"platform": platform.platform(), "cpus": os.cpu_count()}
    report[args.section or args.part] = section
    atomic_write_json(args.out, report)
    print(json.dumps({k: v for k, v in section.items() if k != "arms"}, indent=1)[:4000])
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
