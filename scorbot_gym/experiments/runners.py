"""Run a sweep's model jobs: in a local process pool (default) or as Ray tasks.

Both runners have one contract, ``runner.map(jobs) -> results`` in the jobs' order, and run the
same top-level :func:`~scorbot_gym.experiments.trial.run_model_job`; results are cached per
trial on disk by the job itself, so either runner resumes an interrupted sweep. Ray is the
engine for when a sweep outgrows one machine (``RayRunner("auto")`` or ``"ray://head:10001"``
joins a cluster, whose workers must share the cache directory); ``RayRunner()`` starts a local
instance.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import Protocol

from scorbot_gym.data import cache_folder
from scorbot_gym.experiments.spec import SweepSpec
from scorbot_gym.experiments.trial import (
    ModelJob,
    ViewsJob,
    render_job_views,
    run_model_job,
    views_jobs,
)
from scorbot_gym.experiments.workers import worker_pool

Job = ModelJob | ViewsJob  # any picklable value a top-level ``work`` function takes
Work = Callable[[Job], dict]


class Runner(Protocol):
    def map(self, jobs: Sequence[Job], work: Work = run_model_job) -> list[dict]: ...


def _apply(work: Work, job: Job) -> dict:
    return work(job)


class LocalRunner:
    """``jobs`` worker processes (spawned: no GL context or thread pool is inherited); with
    ``jobs=1`` everything runs in this process."""

    def __init__(self, jobs: int = 1, progress: Callable[[int, int], None] | None = None):
        if jobs < 1:
            raise ValueError(f"jobs must be >= 1, got {jobs}")
        self.jobs, self.progress = jobs, progress

    def map(self, jobs: Sequence[Job], work: Work = run_model_job) -> list[dict]:
        """``work(job)`` for every job (a picklable top-level function or partial)."""
        out: list[dict] = []
        if self.jobs == 1 or len(jobs) <= 1:
            for i, job in enumerate(jobs):
                out.append(work(job))
                if self.progress:
                    self.progress(i + 1, len(jobs))
            return out
        with worker_pool(min(self.jobs, len(jobs))) as pool:
            futures = [pool.submit(work, job) for job in jobs]
            for i, f in enumerate(futures):
                out.append(f.result())
                if self.progress:
                    self.progress(i + 1, len(jobs))
        return out


class RayRunner:
    """The same jobs as Ray tasks (one CPU each). ``address=None`` starts a local Ray instance
    (``num_cpus`` caps it), otherwise connects to ``address`` ("auto", "ray://host:port").
    A Ray instance this runner started is shut down after ``map``."""

    def __init__(self, address: str | None = None, num_cpus: int | None = None):
        try:
            import ray  # noqa: F401
        except ImportError as exc:
            raise ImportError("the Ray runner needs Ray: pip install 'scorbot-gym[ray]'") from exc
        self.address, self.num_cpus = address, num_cpus

    def map(self, jobs: Sequence[Job], work: Work = run_model_job) -> list[dict]:
        import os

        import ray

        started = False
        if not ray.is_initialized():
            env = {k: os.environ[k] for k in ("PYTHONPATH", "MUJOCO_GL") if k in os.environ}
            kw = {"runtime_env": {"env_vars": env}} if env else {}
            if self.address is None:
                kw.update(num_cpus=self.num_cpus, include_dashboard=False)
            ray.init(address=self.address, log_to_driver=False, **kw)
            started = True
        try:
            task = ray.remote(num_cpus=1)(_apply)
            return ray.get([task.remote(work, job) for job in jobs])
        finally:
            if started:
                ray.shutdown()


def make_jobs(spec: SweepSpec, cache_dir: str | None = None) -> list[ModelJob]:
    """One job per (estimator, object): each fits one model and runs all occlusion levels."""
    cache = str(cache_folder(cache_dir))
    pert = tuple(sorted(spec.perturbation.to_dict().items()))
    return [
        ModelJob(
            spec.protocol,
            str(est),
            obj,
            spec.seed,
            spec.occlusions,
            spec.width,
            spec.height,
            spec.test_views,
            spec.train_stride,
            pert,
            cache,
        )  # fmt: skip
        for est in spec.estimator_specs
        for obj in spec.object_names
    ]


def run_sweep(
    spec: SweepSpec,
    runner: Runner | None = None,
    cache_dir: str | None = None,
    work: Work = run_model_job,
) -> dict:
    """Run (or resume) ``spec``; returns the per-trial records and the run's statistics.
    ``work`` runs one job (default: fit or load its model, run its trials, cached).

    Each object's views are rendered first, one job per object on the runner
    (:func:`~scorbot_gym.experiments.trial.views_jobs`): otherwise every worker that reaches an
    object before its views are cached renders them again. ``stats`` holds the whole run's
    ``wall_s`` (that phase's ``views_wall_s`` included) and, per estimator, the summed wall
    ``job_s``, CPU ``job_cpu_s`` and ``fit_s`` of its jobs (``by_estimator``: what a larger run
    would cost; on a shared machine the CPU seconds are the figure to plan with).

    Aggregate with :func:`scorbot_gym.experiments.aggregate.aggregate`.
    """
    runner = runner or LocalRunner()
    jobs = make_jobs(spec, cache_dir)
    t0 = time.perf_counter()
    views = views_jobs(jobs)
    prepared = runner.map(views, render_job_views) if views else []
    views_wall = time.perf_counter() - t0
    results = runner.map(jobs, work)
    stats: dict = {"jobs": len(jobs), "wall_s": round(time.perf_counter() - t0, 2),
                   "views_jobs": len(views), "views_wall_s": round(views_wall, 2)}  # fmt: skip
    for key in ("views_s", "views_cpu_s"):
        stats[key] = round(sum(r["stats"][key] for r in prepared), 2)
    by_estimator: dict[str, dict] = {}
    for job, r in zip(jobs, results, strict=True):
        for k, v in r["stats"].items():
            stats[k] = stats.get(k, 0) + v
        cost = by_estimator.setdefault(job.estimator, {"jobs": 0})
        cost["jobs"] += 1
        for key in ("job_s", "job_cpu_s", "fit_s"):
            cost[key] = cost.get(key, 0.0) + r["stats"].get(key, 0.0)
    for key in ("fit_s", "job_s", "job_cpu_s"):
        stats[key] = round(stats.get(key, 0.0), 2)
    stats["by_estimator"] = {
        est: {k: round(v, 2) for k, v in cost.items()} for est, cost in by_estimator.items()
    }
    stats["runner"] = type(runner).__name__
    trials = [t for r in results for t in r["trials"]]
    return {"spec": spec.to_dict(), "trials": trials, "stats": stats}
