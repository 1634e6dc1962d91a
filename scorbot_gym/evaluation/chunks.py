"""Seeded episode runs split into chunks of seeds, run in worker processes.

Every arm of a comparison runs episodes ``seed, seed + 1, ...``, and each episode depends on its
seed alone (the env is reset with it, the policy re-seeded with it), so an arm's seeds can be
cut into consecutive chunks, each run by its own process on its own env, and joined again in
seed order: the results are the same whatever the number of processes. The comparison
(:mod:`scorbot_gym.evaluation.compare`) and the closed-loop rollouts
(:func:`scorbot_gym.evaluation.rollout.run_rollouts`) both run their arms here.

Chunks are sized for the whole batch, not per arm: about :data:`CHUNKS_PER_JOB` chunks per
process in all, so that one long arm (the estimator's, or one with 220 episodes beside arms of
44) does not keep one process busy while the others idle; never under
:data:`MIN_CHUNK_EPISODES` episodes (each chunk builds its env and loads its models again).
"""

from __future__ import annotations

import functools
import itertools
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

#: about this many chunks per worker process in all (the last ones then finish close together)
CHUNKS_PER_JOB = 4
#: the fewest episodes in a chunk (unless an arm has fewer): each chunk builds its own env
MIN_CHUNK_EPISODES = 10


def plan_chunks(tasks: Sequence[tuple[int, int]], jobs: int) -> list[list[tuple[int, int]]]:
    """Per task ``(episodes, first seed)``: its chunks ``(episodes, first seed)`` in seed order.

    One chunk per task when ``jobs == 1``; else chunks of about ``total / (CHUNKS_PER_JOB *
    jobs)`` episodes, at least :data:`MIN_CHUNK_EPISODES`, an arm's seeds cut into near-equal
    consecutive runs.
    """
    if jobs < 1:
        raise ValueError(f"jobs must be >= 1, got {jobs}")
    if any(n < 1 for n, _ in tasks):
        raise ValueError(f"every task needs >= 1 episode, got {[n for n, _ in tasks]}")
    total = sum(n for n, _ in tasks)
    size = max(MIN_CHUNK_EPISODES, -(-total // (CHUNKS_PER_JOB * jobs)))
    plans = []
    for episodes, seed in tasks:
        k = 1 if jobs == 1 else max(1, min(-(-episodes // size), episodes // MIN_CHUNK_EPISODES))
        bounds = [int(b) for b in np.linspace(0, episodes, k + 1).round()]
        plans.append([(b - a, seed + a) for a, b in itertools.pairwise(bounds)])
    return plans


def parallel(jobs: int, ray: str | None) -> bool:
    """Whether chunks run in workers (processes or Ray tasks), so a chunk's arguments take a
    worker's settings (no progress bar, one thread)."""
    return jobs > 1 or ray is not None


def _call(run: Callable[..., Any], args: tuple) -> Any:
    return run(*args)


def run_chunked(
    run: Callable[..., Any],
    tasks: Sequence[tuple[int, int]],
    chunk_args: Callable[[int, int, int], tuple],
    jobs: int = 1,
    ray: str | None = None,
) -> list[list[Any]]:
    """Run every task's chunks (:func:`plan_chunks`); per task, the outputs of its chunks in
    seed order.

    ``run(*chunk_args(task_index, episodes, first_seed))`` runs one chunk; with ``jobs > 1`` in
    ``jobs`` spawned worker processes (:func:`~scorbot_gym.experiments.workers.worker_pool`: a
    forked child of a process that has rendered cannot render), so ``run`` is a module-level
    function and its arguments pickle. Chunks are queued round-robin over the tasks (the first
    chunk of every task, then the second, ...): every task starts early, so an arm whose
    episodes are slow is never left to start last and finish alone.

    ``ray`` runs the chunks as Ray tasks instead (:class:`~scorbot_gym.experiments.RayRunner`):
    ``"local"`` starts a local Ray instance of ``jobs`` CPUs, an address (``"auto"``,
    ``"ray://head:10001"``) joins a cluster, whose workers must have the package (and, for
    the default pose models, a shared cache); chunks are planned for ``jobs`` workers (at least
    two) either way. The results are the same as in processes.
    """
    if ray is not None:
        from scorbot_gym.experiments.runners import RayRunner

        local = ray == "local"
        runner = RayRunner(None if local else ray, num_cpus=jobs if local else None)
        plans = plan_chunks(tasks, max(jobs, 2))
        flat = [(i, chunk) for i, plan in enumerate(plans) for chunk in plan]
        outs = iter(runner.map([chunk_args(i, *c) for i, c in flat], functools.partial(_call, run)))
        return [[next(outs) for _ in plan] for plan in plans]
    plans = plan_chunks(tasks, jobs)
    if jobs == 1:
        return [[run(*chunk_args(i, *chunk)) for chunk in plan] for i, plan in enumerate(plans)]
    from scorbot_gym.experiments.workers import worker_pool

    order = [
        (i, j)
        for j in range(max(len(p) for p in plans))
        for i, plan in enumerate(plans)
        if j < len(plan)
    ]
    with worker_pool(min(jobs, len(order))) as pool:
        futures = {(i, j): pool.submit(run, *chunk_args(i, *plans[i][j])) for i, j in order}
        return [[futures[i, j].result() for j in range(len(plan))] for i, plan in enumerate(plans)]
