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
angle, the catalogue drawn, the scripted controller; every arm is a pose source (``--arms``):
``oracle`` (the ceiling), ``manifold`` (background subtraction + the default models, no
privileged input), ``chance`` (the image-blind answer: the same source and segmentation with
the ``chance`` estimator in place of the models, a constant rotation, the training views'
medoid, placed at the silhouette as every baseline places it) and ``resting`` (the simple
baseline: the resting-view models that the tilted ones replaced,
:data:`~scorbot_gym.perception.training.RESTING_TRAINING`); ``manifold_held`` is ``manifold``
with the table-top prior decided once an episode and held (``support="table_memory"``). The
image arms are given the target's identity, or with ``--recognize`` recognise it as the main
job does (a section of its own: ``--section loop_recognize``). Per arm: grasp success,
success@5deg of the valid estimates (pooled over every estimate of every episode; an invalid
estimate is not counted there, the valid rate is beside it), the median rotation error (over
episodes, of each episode's median, as the rollout summary takes it), ms per estimate; and the
same split by the target's symmetry (``by_symmetry``: ``none`` is the banana alone, ``axial``
and ``discrete`` the others, ``symmetric`` both), since a symmetric object forgives rotation
errors that an asymmetric one does not.

Both parts update their own section of ``--out`` (default: a new
``runs/tilted_in_loop-<time>/tilted_in_loop.json``; the committed record is ``--out
benchmarks/results/tilted_in_loop.json --overwrite``, an existing file being updated only with
``--overwrite``); ``loop``
merges its arms into a section of the same episodes, tilts and seed (an arm run again replaces
its record, the others stay as measured) and recomputes the totals over all of them.

    python benchmarks/tilted_in_loop.py models [--jobs 2] [--objects box cylinder]
    python benchmarks/tilted_in_loop.py loop [--episodes 70] [--tilts 0 10 20 30] [--jobs 2]
        [--arms oracle manifold chance resting manifold_held] [--recognize --section NAME]
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
#: the closed-loop arms: label -> what its pose source is (``models``: which model set the
#: ``manifold`` source runs; ``None`` for the oracle)
LOOP_ARMS = {
    "oracle": "the true pose (privileged: the ceiling)",
    "manifold": "the default models (IN_LOOP_TRAINING)",
    "chance": "the chance estimator fitted on IN_LOOP_TRAINING's views (image-blind rotation)",
    "resting": "the resting-view models (RESTING_TRAINING, the default before)",
    "manifold_held": "the default models, the table-top prior decided once an episode on clear "
    "views and held (support='table_memory')",
    "manifold_held_appearance": "manifold_held, recognised by appearance over every class "
    "(recognizer='appearance'; with --recognize)",
    "manifold_calibrated": "manifold_held_appearance with the fixed cameras re-calibrated from "
    "the arm's silhouette (calibration='arm'; the defaults since 2026-11-28)",
}
#: the recogniser of each image arm (with --recognize) where it is not FLR's shortlist decided by
#: appearance, the default the committed arms were measured with (appearance since 2026-11-27)
ARM_RECOGNIZER = {"manifold_held_appearance": "appearance", "manifold_calibrated": "appearance"}
#: the ``support`` of each image arm's source: the per-estimate prior the committed arms were
#: measured with (the default until 2026-11-27), the held one (the default since) by name
ARM_SUPPORT = {"manifold_held": "table_memory", "manifold_held_appearance": "table_memory",
               "manifold_calibrated": "table_memory"}  # fmt: skip
ARM_SUPPORT_DEFAULT = "table"
#: the arms whose fixed cameras are re-calibrated from the arm's silhouette (the others were
#: measured with the cameras as calibrated, the default until 2026-11-28)
ARM_CALIBRATION = {"manifold_calibrated": "arm"}
#: the arms run unless ``--arms`` says otherwise
DEFAULT_LOOP_ARMS = ("oracle", "manifold", "chance", "resting")
#: symmetry groups of ``by_symmetry`` (the target's :class:`pose.symmetry.Symmetry` kind)
SYMMETRY_GROUPS = {
    "none": ("none",),
    "axial": ("axial",),
    "discrete": ("discrete",),
    "symmetric": ("axial", "discrete"),
}


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
    label: str,
    pose: str,
    tilt: float,
    episodes: int,
    seed: int,
    objects,
    pose_model,
    recognize: bool = False,
) -> dict:
    import cv2

    from scorbot_gym.evaluation.rollout import RolloutConfig, run_rollout

    cv2.setNumThreads(1)
    image = pose == "manifold"  # recognition and the support prior are the image source's
    config = RolloutConfig(
        pose=pose, tilt_deg=tilt, episodes=episodes, seed=seed, objects=objects,
        pose_model=pose_model if image else None, recognize=recognize and image,
        support=ARM_SUPPORT.get(label, ARM_SUPPORT_DEFAULT) if image else None,
        recognizer=ARM_RECOGNIZER.get(label, "flr+appearance") if image else None,
        calibration=ARM_CALIBRATION.get(label, "none") if image else None,
    )  # fmt: skip
    t0 = time.perf_counter()
    summary, _ = run_rollout(config, progress=False)
    results = summary.pop("results")
    if tilt > 0:
        summary["settled_tilt_deg"] = _settled_tilts(config)
    summary.update(
        label=label,
        tilt_deg=tilt,
        wall_s=round(time.perf_counter() - t0, 1),
        **_estimate_counts(results),
        by_symmetry=_by_symmetry(results),
    )
    return summary


def _estimate_counts(results: list[dict]) -> dict:
    """Valid estimates and the share of them within 5 degrees, pooled over every estimate of
    these episodes, and the median over episodes of each episode's median rotation error."""
    import numpy as np

    perception = [r["perception"] for r in results if r.get("perception")]
    valid = sum(p["valid"] for p in perception)
    hits = sum(p["valid"] * (p["success_5deg"] or 0.0) for p in perception)
    errors = [p["median_rot_err_deg"] for p in perception if p["median_rot_err_deg"] is not None]
    return {
        "estimates_valid": valid,
        "success_5deg_of_valid_estimates": round(hits / valid, 4) if valid else None,
        "median_rot_err_deg": round(float(np.median(errors)), 3) if errors else None,
    }


def _by_symmetry(results: list[dict]) -> dict:
    """Episodes, grasps and the estimate figures per symmetry group of the target."""
    from scorbot_gym.objects import get_object

    kinds = {r["object_name"]: get_object(r["object_name"]).symmetry.kind for r in results}
    out = {}
    for group, members in SYMMETRY_GROUPS.items():
        mine = [r for r in results if kinds[r["object_name"]] in members]
        out[group] = {
            "objects": sorted({r["object_name"] for r in mine}),
            "episodes": len(mine),
            "successes": sum(bool(r["success"]) for r in mine),
            **(_estimate_counts(mine) if mine else {}),
        }
    return out


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


def arm_models(label: str, objects, jobs: int, progress: bool = True) -> str | None:
    """The model file the ``manifold`` source runs for arm ``label`` (trained or fitted once
    here, not per worker); ``None`` for the oracle."""
    from scorbot_gym.perception.baseline_models import baseline_models
    from scorbot_gym.perception.training import (
        IN_LOOP_TRAINING,
        RESTING_TRAINING,
        default_models_path,
        default_pose_models,
    )

    if label not in LOOP_ARMS:
        raise ValueError(f"unknown arm {label!r}; the arms: {', '.join(LOOP_ARMS)}")
    if label == "oracle":
        return None
    if label == "chance":
        return str(baseline_models("chance", IN_LOOP_TRAINING, objects, jobs, progress))
    training = RESTING_TRAINING if label == "resting" else IN_LOOP_TRAINING  # manifold(_held)
    default_pose_models(objects=objects, jobs=jobs, progress=progress, training=training)
    return str(default_models_path(objects=objects, training=training))


def _totals(arms: list[dict], labels) -> dict:
    """Per arm, over its tilted runs and (apart) over its resting ones (tilt 0)."""
    from scorbot_gym.evaluation.summary import wilson_interval

    totals = {}
    for label in labels:
        for kind, keep in (("tilted", lambda t: t > 0), ("resting", lambda t: t == 0)):
            mine = [a for a in arms if a["label"] == label and keep(a["tilt_deg"])]
            if not mine:
                continue
            n, ok = sum(a["episodes"] for a in mine), sum(a["successes"] for a in mine)
            totals[f"{label}_{kind}"] = {
                "episodes": n,
                "grasp_success": round(ok / n, 4),
                "grasp_success_ci95": [round(v, 4) for v in wilson_interval(ok, n)],
                **_pooled(mine),
                "median_rot_err_deg_of_arms": [
                    (a.get("perception") or {}).get("median_rot_err_deg") for a in mine
                ],
                "median_estimate_ms_of_arms": [
                    (a.get("perception") or {}).get("median_estimate_ms") for a in mine
                ],
                "by_symmetry": _pooled_by_symmetry(mine),
            }
    return totals


def _pooled(records: list[dict]) -> dict:
    """Valid estimates and their share within 5 degrees, pooled over ``records`` (arms, or
    one symmetry group of several arms)."""
    valid = sum(r.get("estimates_valid") or 0 for r in records)
    hits = sum(
        (r.get("estimates_valid") or 0) * (r.get("success_5deg_of_valid_estimates") or 0)
        for r in records
    )
    return {
        "estimates_valid": valid,
        "success_5deg_of_valid_estimates": round(hits / valid, 4) if valid else None,
    }


def _pooled_by_symmetry(arms: list[dict]) -> dict:
    """``by_symmetry`` over several arms: grasps add up, estimates pool; the median error is
    given per arm (a median of medians would hide their spread). Arms measured before the
    split was recorded give their grasps from ``per_object`` and no estimate figures
    (``estimates_split`` false)."""
    from scorbot_gym.evaluation.summary import wilson_interval

    out = {}
    for group in SYMMETRY_GROUPS:
        rows = [_symmetry_group(a, group) for a in arms]
        n, ok = sum(r["episodes"] for r in rows), sum(r["successes"] for r in rows)
        split = all("estimates_valid" in r for r in rows if r["episodes"])
        out[group] = {
            "objects": sorted({o for r in rows for o in r["objects"]}),
            "episodes": n,
            "grasp_success": round(ok / n, 4) if n else None,
            "grasp_success_ci95": [round(v, 4) for v in wilson_interval(ok, n)] if n else None,
            "estimates_split": split,
            **(_pooled(rows) if split else {}),
            "median_rot_err_deg_of_arms": [r.get("median_rot_err_deg") for r in rows],
        }
    return out


def _symmetry_group(arm: dict, group: str) -> dict:
    """One arm's record of a symmetry group: measured, or (an arm measured before the split
    was recorded) its episodes and grasps summed from ``per_object``."""
    if "by_symmetry" in arm:
        return arm["by_symmetry"][group]
    from scorbot_gym.objects import get_object

    members = SYMMETRY_GROUPS[group]
    mine = {n: o for n, o in arm["per_object"].items() if get_object(n).symmetry.kind in members}
    return {
        "objects": sorted(mine),
        "episodes": sum(o["episodes"] for o in mine.values()),
        "successes": sum(o["successes"] for o in mine.values()),
    }


def run_loop(args: argparse.Namespace) -> dict:
    """The arms of ``args.arms`` at every tilt, and the record of this run."""
    objects = tuple(args.objects) if args.objects else None
    models = {label: arm_models(label, objects, args.jobs) for label in args.arms}
    runs = []
    for i, tilt in enumerate(args.tilts):
        for label in args.arms:
            pose = "oracle" if label == "oracle" else "manifold"
            default = label.startswith("manifold") and not objects
            model = None if default else models[label]
            seed = args.seed + 1000 * i
            runs.append((label, pose, tilt, args.episodes, seed, objects, model, args.recognize))
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
            f"median {a['median_rot_err_deg']} deg  ms {p.get('median_estimate_ms')}",
            flush=True,
        )
    run = {
        "arms": list(args.arms),
        "wall_s": round(time.perf_counter() - t0, 1),
        "jobs": args.jobs,
        "machine": _machine(),
    }
    return {"arms": arms, "run": run}


def merge_loop(new: dict, previous: dict | None, args: argparse.Namespace) -> dict:
    """The ``loop`` section: the arms just run, and those of ``previous`` (the section as
    written now, of the same episodes, tilts and seed) that were not run again, as measured;
    totals over all of them. Read at the end of a run, so that runs of other arms that finished
    meanwhile are kept too."""
    previous = previous or {}
    kept = [a for a in previous.get("arms", []) if a["label"] not in args.arms]
    for a in kept:  # measured before the median over episodes was recorded per arm
        a.setdefault("median_rot_err_deg", (a.get("perception") or {}).get("median_rot_err_deg"))
    runs = previous.get("runs") or (
        [{k: previous.get(k) for k in ("wall_s", "jobs", "machine")}] if kept else []
    )
    if runs and "arms" not in runs[0]:  # the first run, recorded before runs were
        runs[0]["arms"] = list(dict.fromkeys(a["label"] for a in kept))
    runs = [{**r, "arms": [a for a in r["arms"] if a not in args.arms]} for r in runs]
    runs = [r for r in runs if r["arms"]]  # the arms that a run measured and that are kept
    runs.append(new["run"])
    arms = kept + new["arms"]
    labels = list(dict.fromkeys(a["label"] for a in arms))
    return {
        "objects": list(args.objects) if args.objects else "catalogue",
        "tilts_deg": list(args.tilts),
        "episodes_per_tilt": args.episodes,
        "seed": args.seed,
        "identity": "recognised" if args.recognize else "given",
        "arm_pose_sources": {label: LOOP_ARMS[label] for label in labels},
        "arms": arms,
        "totals": _totals(arms, labels),
        "targets": {"success_5deg": 0.8, "grasp_success": 0.9},
        "runs": runs,
    }


def _machine() -> dict:
    return {
        "platform": platform.platform(),
        "cpus": os.cpu_count(),
        "load_1min": round(os.getloadavg()[0], 2),
    }


def _same_loop(section: dict | None, args: argparse.Namespace) -> bool:
    """Whether a written ``loop`` section measured the same episodes (its arms can be kept)."""
    objects = list(args.objects) if args.objects else "catalogue"
    return bool(section) and (
        section.get("objects"), section.get("tilts_deg"), section.get("episodes_per_tilt"),
        section.get("seed"), section.get("identity", "given"),
    ) == (objects, list(args.tilts), args.episodes, args.seed,
          "recognised" if args.recognize else "given")  # fmt: skip


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
    lp.add_argument(
        "--recognize",
        action="store_true",
        help="the image arms recognise the target (top + side, the rollout default) instead "
        "of being given its identity; write it to its own --section",
    )
    lp.add_argument(
        "--arms", nargs="+", choices=list(LOOP_ARMS), default=list(DEFAULT_LOOP_ARMS),
        help="pose sources to run; the section's other arms of the same episodes are kept",
    )  # fmt: skip
    from scorbot_gym.experiments.outputs import Outputs, add_overwrite_option

    ap.add_argument(
        "--out",
        type=Path,
        default=None,
        help="where to write (default: runs/tilted_in_loop-<time>/tilted_in_loop.json); an "
        "existing file is updated (its other sections and arms kept) only with --overwrite",
    )
    add_overwrite_option(ap)
    ap.add_argument("--section", default=None, help="key of the JSON to write (default: part)")
    args = ap.parse_args(argv)
    try:  # before any work: an existing file is not replaced unless asked
        args.out = Outputs("tilted_in_loop", args.overwrite).path(
            args.out, "tilted_in_loop.json", "--out", companions=[".png"]
        )
    except ValueError as exc:
        ap.error(str(exc))
    if args.jobs < 1 or getattr(args, "episodes", 1) < 1:
        ap.error("--jobs and --episodes must be >= 1")
    if any(not 0 <= t <= 45 for t in getattr(args, "tilts", [])):
        ap.error("--tilts must be angles in [0, 45] degrees (0: resting, no stand)")

    from pose.fileio import atomic_write_json

    key = args.section or args.part
    if args.part == "models":
        section = run_models(args)
        section["machine"] = _machine()
    else:
        if len(set(args.arms)) != len(args.arms):
            ap.error("--arms names an arm twice")
        new = run_loop(args)
    report = json.loads(args.out.read_text()) if args.out.is_file() else {}  # as written now
    if args.part == "loop":
        previous = report.get(key)
        section = merge_loop(new, previous if _same_loop(previous, args) else None, args)
    report[key] = section
    atomic_write_json(args.out, report)
    print(json.dumps({k: v for k, v in section.items() if k != "arms"}, indent=1)[:4000])
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
