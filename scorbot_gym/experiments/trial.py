"""One unit of sweep work: fit one estimator on one object's protocol training views, then
predict its held-out views at each occlusion level.

A *trial* is (protocol, estimator, object, seed, occlusion). Trials sharing everything but the
occlusion share one fitted model, so the unit of work (:class:`ModelJob`) is the model: it fits
once (or loads the model from the content-keyed model cache) and runs its trials. Each trial's
per-view records are cached as one JSON file under a content key, written atomically, so an
interrupted sweep resumes where it stopped and a repeated one fits nothing. Keys include a hash
of the ``pose`` package source and of the scene, so after editing an estimator or the renderer
no stale number is served (coarse but safe: any edit there recomputes every trial). Unreadable
cache entries are discarded and recomputed.

A job is a plain, picklable value and :func:`run_model_job` a top-level function, so a process
pool and Ray run the same code.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from dataclasses import asdict, dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from pose.fileio import atomic_write_json
from pose.metrics import rotation_error_deg

TRIAL_FORMAT = 3  # 3: a model-selecting estimator's choice per trial (``selection``)


@dataclass(frozen=True)
class ModelJob:
    """Everything one worker needs; see :func:`run_model_job`."""

    protocol: str
    estimator: str  # canonical estimator spec string
    object_name: str
    seed: int
    occlusions: tuple[float, ...]
    width: int
    height: int
    test_views: int | None
    train_stride: int
    perturbation: tuple[tuple[str, float], ...]  # Perturbation.to_dict() items
    cache_dir: str


@lru_cache(maxsize=1)
def code_fingerprint() -> str:
    """Hash of the ``pose`` package source and the view renderer's scene fingerprint."""
    import pose
    from scorbot_gym.data.views import _scene_fingerprint

    h = hashlib.sha256(_scene_fingerprint().encode())
    for f in sorted(Path(pose.__file__).parent.rglob("*.py")):
        h.update(str(f.relative_to(Path(pose.__file__).parent)).encode() + f.read_bytes())
    return h.hexdigest()[:16]


def _key(payload: dict) -> str:
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()[:24]


def model_key(job: ModelJob) -> str:
    from scorbot_gym.data.protocols import get_protocol

    return _key({
        "protocol": job.protocol, "version": get_protocol(job.protocol).version,
        "estimator": job.estimator, "object": job.object_name, "seed": job.seed,
        "size": [job.width, job.height], "train_stride": job.train_stride,
        "code": code_fingerprint(),
    })  # fmt: skip


def trial_key(job: ModelJob, occlusion: float) -> str:
    from scorbot_gym.data import perturbations
    from scorbot_gym.data.protocols import get_protocol

    payload = {
        "model": model_key(job), "occlusion": occlusion, "test_views": job.test_views,
        "perturbation": dict(job.perturbation), "format": TRIAL_FORMAT,
    }  # fmt: skip
    if perturbations.Perturbation(**dict(job.perturbation)).active:  # as the views' key does
        payload["perturbation_code"] = perturbations.code_fingerprint()
    if get_protocol(job.protocol).clutter_distractors is not None:  # scenes of real occluders
        from scorbot_gym.data.clutter_views import code_fingerprint as clutter_code

        payload["clutter_code"] = clutter_code()
        if job.test_views is not None:  # it counts scenes now; it once cut each bin's views
            payload["test_views_are"] = "scenes"
    return _key(payload)


def trial_path(job: ModelJob, occlusion: float) -> Path:
    return Path(job.cache_dir) / "experiments" / "trials" / f"{trial_key(job, occlusion)}.json"


def read_trial(path: Path) -> dict | None:
    """A cached trial, or None (missing; an unreadable entry is deleted)."""
    if not path.is_file():
        return None
    try:
        rec = json.loads(path.read_text())
        if rec.get("format") != TRIAL_FORMAT or not isinstance(rec.get("views"), dict):
            raise ValueError("stale format")
        return rec
    except (OSError, ValueError):
        path.unlink(missing_ok=True)
        return None


def model_path(job: ModelJob) -> Path:
    """Where the job's fitted model is cached (estimators that can save and load)."""
    return Path(job.cache_dir) / "experiments" / "models" / f"{model_key(job)}.npz"


def job_train_views(job: ModelJob) -> list:
    """The job's training views: the protocol's, every ``train_stride``-th, with depth
    (estimators that lift keypoints to 3-D, PnP, train on it; test views are RGB)."""
    from scorbot_gym.data.protocols import train_views

    by_cam = train_views(job.protocol, job.object_name, seed=job.seed, depth=True,
                         width=job.width, height=job.height, cache_dir=job.cache_dir)  # fmt: skip
    return [lv for cam in by_cam.values() for lv in cam[:: job.train_stride]]


@dataclass(frozen=True)
class ViewsJob:
    """Render (or find cached) one object's views before the model jobs that need them:
    ``job`` names the object and the sweep's settings; ``train`` says whether some model of it
    is still to be fitted, ``occlusions`` the levels some trial of it still lacks."""

    job: ModelJob
    train: bool
    occlusions: tuple[float, ...]


def render_job_views(views: ViewsJob) -> dict:
    """Bring a :class:`ViewsJob`'s views into the view cache (the same calls the model jobs
    make, so they find them there); returns ``{"stats": {"views_s", "views_cpu_s"}}`` (wall
    and this process's CPU seconds)."""
    t0, c0 = time.perf_counter(), time.process_time()
    if views.train:
        job_train_views(views.job)
    for occ in views.occlusions:
        trial_views(views.job, occ)
    return {"stats": {"views_s": time.perf_counter() - t0,
                      "views_cpu_s": time.process_time() - c0}}  # fmt: skip


def views_jobs(jobs: list[ModelJob]) -> list[ViewsJob]:
    """One :class:`ViewsJob` per object that some of ``jobs`` still has work for: run before
    them, so that each object's views are rendered once, not by every worker that reaches the
    object before they are cached. Nothing for a sweep whose trials are all cached."""
    out: dict[str, ViewsJob] = {}
    for job in jobs:
        todo = tuple(o for o in job.occlusions if not trial_path(job, o).is_file())
        if not todo:
            continue
        prev = out.get(job.object_name)
        train = not model_path(job).is_file() or (prev is not None and prev.train)
        levels = tuple(sorted(set(todo) | set(prev.occlusions if prev else ())))
        out[job.object_name] = ViewsJob(prev.job if prev else job, train, levels)
    return list(out.values())


def fitted_model(job: ModelJob, stats: dict | None = None):
    """The job's fitted estimator, from the model cache when the estimator can save and load,
    else fitted on the protocol's training views (rendered or read only then) and cached.
    The object's symmetry goes to estimators whose ``fit`` takes it (a validation selection).
    ``ValueError`` where the estimator refuses the views; ``stats`` counts fits and cache hits."""
    from pose.composition import fit_estimator
    from scorbot_gym.experiments.spec import EstimatorSpec
    from scorbot_gym.objects import get_object

    stats = {"fits": 0, "fit_s": 0.0, "model_cache_hits": 0} if stats is None else stats
    path = model_path(job)
    est = EstimatorSpec.parse(job.estimator).make()
    can_save = callable(getattr(est, "save", None)) and callable(getattr(type(est), "load", None))
    if can_save and path.is_file():
        try:
            loaded = type(est).load(path)
            stats["model_cache_hits"] += 1
            return loaded
        except (OSError, ValueError, KeyError, TypeError):
            path.unlink(missing_ok=True)  # unreadable: refitted and rewritten below
    train = job_train_views(job)
    views = [lv.view for lv in train]
    poses = np.stack([lv.camera_from_object for lv in train])
    t0 = time.perf_counter()
    fit_estimator(est, views, poses, get_object(job.object_name).symmetry)
    stats["fits"] += 1
    stats["fit_s"] += time.perf_counter() - t0
    if can_save:
        try:
            est.save(path)
        except (OSError, ValueError, TypeError, NotImplementedError):
            path.unlink(missing_ok=True)  # not cacheable: the trials are still cached
    return est


def selection_record(est) -> dict | None:
    """What a model-selecting estimator (``select(...)``) chose for this object and why: the
    chosen candidate, every candidate's cross-validated success@5° and median error on the
    training views (None where it could not be fitted), and the candidates' fit errors. A
    per-object choice is half of such an estimator's result: a table of its success alone
    cannot say whether the keypoint method or the image-blind prior answered. None for
    estimators that select nothing."""
    from pose.selection import ValidationSelection

    if not isinstance(est, ValidationSelection):
        return None

    def finite(values) -> list[float | None]:
        return [float(v) if np.isfinite(v) else None for v in np.asarray(values, float)]

    return {
        "selected": est.best_name_,
        "candidates": list(est.candidate_names_),
        "cv_success_5deg": finite(est.validation_success_),
        "cv_median_rot_err_deg": finite(est.validation_median_deg_),
        "fit_errors": dict(est.fit_errors_),
    }


class _Unfitted:
    """Stands in for an estimator whose ``fit`` rejected this object's training views (e.g.
    too few SIFT keypoints on a small object): every test view is an invalid answer, so the
    method scores what it can do on the object (nothing) instead of stopping the whole sweep."""

    def __init__(self, reason: str):
        self.reason = reason

    def predict(self, view):
        from pose.view import PoseEstimate

        return PoseEstimate.invalid(f"not fitted: {self.reason}", {"total": 0.0})


def _constant_rotation(spec, camera) -> np.ndarray:
    """The image-blind answer "resting face 0, heading 0" in the test camera's frame."""
    from scorbot_gym.sim.simulation import quat_to_mat

    R_world = quat_to_mat(np.asarray(spec.resting_quats[0], float))
    return camera.camera_from_world[:3, :3] @ R_world


def _score(est, views, spec) -> dict:
    sym = spec.symmetry
    keys = ("rot_err_deg", "coarse_rot_err_deg", "chance_rot_err_deg", "trans_err_m", "valid",
            "ms", "occlusion", "score", "R", "t", "R_gt", "t_gt")  # fmt: skip
    rec: dict[str, list] = {k: [] for k in keys}
    R0 = _constant_rotation(spec, views[0].view.camera) if views else None
    for lv in views:
        t0 = time.perf_counter()
        e = est.predict(lv.view)
        wall_ms = 1e3 * (time.perf_counter() - t0)
        R_gt, t_gt = lv.camera_from_object[:3, :3], lv.camera_from_object[:3, 3]
        R, t = np.asarray(e.rotation, float), np.asarray(e.translation, float)
        coarse = getattr(e, "rotation_coarse", None)
        rec["rot_err_deg"].append(rotation_error_deg(R, R_gt, sym))
        rec["coarse_rot_err_deg"].append(
            rotation_error_deg(coarse, R_gt, sym) if coarse is not None else float("nan")
        )
        rec["chance_rot_err_deg"].append(rotation_error_deg(R0, R_gt, sym))
        rec["trans_err_m"].append(float(np.linalg.norm(t - t_gt)))
        rec["valid"].append(bool(e.valid))
        rec["ms"].append(float(getattr(e, "timings_ms", {}).get("total", wall_ms)))
        rec["occlusion"].append(float(lv.occlusion))
        rec["score"].append(float(getattr(e, "confidence", 1.0 if e.valid else 0.0)))
        rec["R"].append(R.tolist())
        rec["t"].append(t.tolist())
        rec["R_gt"].append(R_gt.tolist())
        rec["t_gt"].append(t_gt.tolist())
    # JSON has no NaN: invalid answers are stored as null
    return {k: [_jsonable(v) for v in vs] for k, vs in rec.items()}


def _jsonable(v):
    if isinstance(v, float):
        return v if np.isfinite(v) else None
    if isinstance(v, list):
        return [_jsonable(x) for x in v]
    return v


def trial_views(job: ModelJob, occlusion: float) -> list:
    """The job's held-out views at one occlusion level (seeded apart from training: seed + 1),
    of its first ``test_views`` test poses (on a clutter protocol: scenes)."""
    from scorbot_gym.data.perturbations import Perturbation
    from scorbot_gym.data.protocols import held_out_views

    return held_out_views(
        job.protocol, job.object_name, occlusion, seed=job.seed + 1, width=job.width,
        height=job.height, cache_dir=job.cache_dir,
        perturbation=Perturbation(**dict(job.perturbation)), n_poses=job.test_views,
    )  # fmt: skip


def trial_record(job: ModelJob, occlusion: float, est, views, estimator: str | None = None) -> dict:
    """One trial: ``est``'s answers to ``views`` scored against the ground truth, labelled
    ``estimator`` (default: the job's spec)."""
    from scorbot_gym.objects import get_object

    obj = get_object(job.object_name)
    rec = {
        "format": TRIAL_FORMAT,
        "protocol": job.protocol,
        "estimator": job.estimator if estimator is None else estimator,
        "object": job.object_name,
        "seed": job.seed,
        "occlusion": occlusion,
        "symmetry": obj.symmetry.kind,
        "views": _score(est, views, obj),
    }
    if isinstance(est, _Unfitted):
        rec["fit_error"] = est.reason
    if (choice := selection_record(est)) is not None:
        rec["selection"] = choice
    return rec


def run_model_job(job: ModelJob) -> dict:
    """Run the job's trials, reading cached ones; returns ``{"trials": [...], "stats": {...}}``.

    The model is fitted (or loaded) only if some trial is not cached yet.
    """
    import cv2

    cv2.setNumThreads(1)  # one worker per core: no nested thread pools
    t0, c0 = time.perf_counter(), time.process_time()
    stats = {"fits": 0, "fit_s": 0.0, "fit_errors": 0, "model_cache_hits": 0, "trials_cached": 0,
             "trials_run": 0}  # fmt: skip
    trials, todo = [], []
    for occ in job.occlusions:
        rec = read_trial(trial_path(job, occ))
        if rec is None:
            todo.append(occ)
        else:
            stats["trials_cached"] += 1
            trials.append(rec)
    if todo:
        est = fitted_or_unfitted(job, stats)
        for occ in todo:
            rec = trial_record(job, occ, est, trial_views(job, occ))
            atomic_write_json(trial_path(job, occ), rec)
            stats["trials_run"] += 1
            trials.append(rec)
    trials.sort(key=lambda r: r["occlusion"])
    # wall and CPU seconds: on a shared machine only the CPU time says what the job costs
    stats["job_s"], stats["job_cpu_s"] = time.perf_counter() - t0, time.process_time() - c0
    return {"trials": trials, "stats": stats, "job": asdict(job)}


def fitted_or_unfitted(job: ModelJob, stats: dict):
    """:func:`fitted_model`, or where the estimator's ``fit`` refuses the object's views (its
    one-line ``ValueError``) a stand-in that answers every view as invalid."""
    try:
        return fitted_model(job, stats)
    except ValueError as exc:
        stats["fit_errors"] = stats.get("fit_errors", 0) + 1
        return _Unfitted(str(exc))


def default_cache_dir() -> str:
    from scorbot_gym.data.views import default_cache_dir as views_cache

    return os.fspath(views_cache())
