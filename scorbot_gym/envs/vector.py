"""Vector envs that pay off on a few CPU cores: ``make_vec_env``.

Stepping N copies of ``ScorbotGrasp-v0`` in N processes only beats one plain env when the
per-step work in each process is large compared with the cost of moving a step between
processes. ``make_vec_env`` builds a :class:`gymnasium.vector.AsyncVectorEnv` set up for that:

- observations (images included) come back through shared memory, not pickled through pipes;
- the per-step ``info`` stays small: the env sends the constant camera calibration at reset
  only (``info["camera_params"]``), not every step;
- ``render_threads`` sets the software rasterizer's (llvmpipe's) threads per worker; by default
  Mesa's own choice (one per core) is kept, which measured faster on a shared 2-core machine;
- at most ``max_concurrency`` workers (default: the cores this process may use) step at once, so
  more envs than cores queue instead of being time-sliced mid-step.

``benchmarks/vector_env.py`` measures the result against one plain env; see the README.
"""

from __future__ import annotations

import os
from typing import Any

import gymnasium as gym

VECTORIZATION_MODES = ("async", "sync")


class _EnvFactory:
    """Picklable ``env_fn``: builds the env, first setting the rendering thread count when it
    runs in a worker process (not in the process that builds the vector env, which also calls
    it once to read the spaces and must keep its own settings)."""

    def __init__(self, env_id: str, env_kwargs: dict[str, Any], render_threads: int | None):
        self.env_id, self.env_kwargs, self.render_threads = env_id, env_kwargs, render_threads
        self.parent_pid = os.getpid()

    def __call__(self) -> gym.Env:
        if self.render_threads is not None and os.getpid() != self.parent_pid:
            # Mesa reads it when the worker's first GL context is made (at its first render).
            os.environ["LP_NUM_THREADS"] = str(self.render_threads)
        return gym.make(self.env_id, **self.env_kwargs)


def available_cores() -> int:
    """CPU cores this process may run on (its affinity mask, not the machine's core count)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def make_vec_env(
    env_id: str = "ScorbotGrasp-v0",
    num_envs: int = 2,
    vectorization_mode: str = "async",
    *,
    render_threads: int | None = None,
    max_concurrency: int | None = -1,
    copy: bool = True,
    context: str | None = None,
    autoreset_mode: str | gym.vector.AutoresetMode = gym.vector.AutoresetMode.NEXT_STEP,
    **env_kwargs: Any,
) -> gym.vector.VectorEnv:
    """``num_envs`` copies of ``gym.make(env_id, **env_kwargs)`` as one vector env.

    Args:
        env_id: a registered id, e.g. ``"ScorbotGrasp-v0"``.
        num_envs: number of sub-environments (>= 1).
        vectorization_mode: ``"async"`` (one process per env, observations in shared memory)
            or ``"sync"`` (all in this process; no parallelism, no inter-process cost).
        render_threads: llvmpipe threads per worker (async only); ``None`` leaves Mesa's default
            (one per core in every worker). Ignored by GPU EGL drivers.
        max_concurrency: most workers stepping at once (async only); ``-1`` means the number of
            cores this process may use, ``None`` no limit.
        copy: return observations copied out of the shared buffers (async only). ``False`` saves
            a copy per step, but the arrays are overwritten by the next ``step``.
        context: ``multiprocessing`` start method for the workers (async only).
        autoreset_mode: Gymnasium's autoreset mode.
        **env_kwargs: passed to ``gym.make`` for every sub-environment (``cameras``, ...).
    """
    if not isinstance(num_envs, int) or num_envs < 1:
        raise ValueError(f"num_envs must be an integer >= 1, got {num_envs!r}")
    if vectorization_mode not in VECTORIZATION_MODES:
        raise ValueError(
            f"vectorization_mode must be one of {VECTORIZATION_MODES}, got {vectorization_mode!r}"
        )
    if render_threads is not None and (not isinstance(render_threads, int) or render_threads < 0):
        raise ValueError(f"render_threads must be an integer >= 0 or None, got {render_threads!r}")
    if max_concurrency is not None and max_concurrency != -1 and max_concurrency < 1:
        raise ValueError(
            f"max_concurrency must be >= 1, -1 (= the usable cores) or None, got {max_concurrency}"
        )
    if vectorization_mode == "sync":
        fns = [_EnvFactory(env_id, env_kwargs, None) for _ in range(num_envs)]
        return gym.vector.SyncVectorEnv(fns, copy=copy, autoreset_mode=autoreset_mode)
    fns = [_EnvFactory(env_id, env_kwargs, render_threads) for _ in range(num_envs)]
    limit = available_cores() if max_concurrency == -1 else max_concurrency
    return gym.vector.AsyncVectorEnv(
        fns,
        shared_memory=True,
        copy=copy,
        context=context,
        autoreset_mode=autoreset_mode,
        max_concurrency=None if limit is None or limit >= num_envs else limit,
    )
