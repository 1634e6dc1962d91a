"""Vector-env workers pinned one per CPU core.

With rendering, a worker's step is a few milliseconds of CPU on one thread, and its caches hold
the scene's vertex buffers and the frame's tiles. Left to the scheduler, a worker woken by the
main process's pipe write is often placed on the core the main process runs on, or moved
between cores, and starts its step with cold caches or behind the other worker. Pinning each
worker to its own core is what Sample Factory does by default and EnvPool offers as an option;
it is opt-in here because a pin is a promise about the whole machine: two jobs that both pin
their workers to cores 0 and 1 share those two cores and leave the rest idle (pass ``cores``
to give each job its own).

    from functools import partial
    envs = gymnasium.vector.AsyncVectorEnv(
        pin_env_fns([partial(gymnasium.make, "scorbot_gym:ScorbotGrasp-v0", cameras=["top"])] * 2),
        shared_memory=True,
    )

The same functions work with stable-baselines3's ``SubprocVecEnv``.

A worker whose env function fails reports that error (:class:`~scorbot_gym.envs.worker.
WorkerEnvFn`, which the pinned functions wrap).
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import gymnasium as gym

from scorbot_gym.envs.worker import WorkerEnvFn


@dataclass(frozen=True)
class PinnedEnvFn:
    """An env factory that first pins the calling worker process to ``core``.

    Called in the main process it only makes the env: Gymnasium's ``AsyncVectorEnv`` builds
    one env there to read the spaces, and an in-process vector env builds all of them there;
    pinning the main process would serialize everything it runs onto one core."""

    env_fn: Callable[[], gym.Env]
    core: int

    def __call__(self) -> gym.Env:
        if multiprocessing.parent_process() is not None:
            os.sched_setaffinity(0, {self.core})
        return WorkerEnvFn(self.env_fn)()


def pin_env_fns(
    env_fns: Sequence[Callable[[], gym.Env]], cores: Sequence[int] | None = None
) -> list[PinnedEnvFn]:
    """``env_fns`` wrapped so that worker ``i`` runs on ``cores[i % len(cores)]``.

    ``cores`` defaults to the cores this process may run on (``os.sched_getaffinity``), so a
    job started under ``taskset`` or in a cgroup cpuset stays inside it.
    """
    allowed = sorted(os.sched_getaffinity(0))
    chosen = allowed if cores is None else list(cores)
    bad = [c for c in chosen if not isinstance(c, int) or c not in allowed]
    if not chosen or bad:
        raise ValueError(
            f"cores must be a non-empty list of cores this process may use {allowed}, got "
            f"{list(cores) if cores is not None else cores!r}"
        )
    if not env_fns:
        raise ValueError("env_fns is empty: give one env function per worker")
    return [PinnedEnvFn(fn, chosen[i % len(chosen)]) for i, fn in enumerate(env_fns)]
