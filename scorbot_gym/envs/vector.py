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

They also make a worker's failure to build its env reach the main process as itself. Gymnasium's
``AsyncVectorEnv`` worker calls the env function before its error handling starts, so an
exception there ends the worker and the main process only sees ``ConnectionResetError`` or
``BrokenPipeError`` on its next call. :class:`WorkerEnvFn` (which ``pin_env_fns`` and
:class:`~scorbot_gym.envs.overlapped.OverlappedVectorEnv` use) hands the worker a stand-in env
that raises the original exception at ``reset``/``step``, which the worker sends back:

    envs = gymnasium.vector.AsyncVectorEnv([WorkerEnvFn(fn) for fn in env_fns])
"""

from __future__ import annotations

import multiprocessing
import os
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import gymnasium as gym


class _UnbuiltSpace(gym.spaces.Dict):
    """The observation space of an env that could not be built: comparing it raises the error.

    ``AsyncVectorEnv`` first asks each worker whether its spaces equal the main process's env's
    (``main_space == worker_space``). Python tries the right operand's ``__eq__`` first when
    its type subclasses the left's, so for a ``Dict`` observation space (every scorbot-gym env)
    this raises the worker's error there, inside the worker's error handling."""

    def __init__(self, error: Exception) -> None:
        super().__init__({})
        self.error = error

    def __eq__(self, other: object) -> bool:
        raise self.error

    __hash__ = None


class _FailedEnv(gym.Env):
    """What a worker holds when its env could not be built: every call raises that error."""

    def __init__(self, error: Exception) -> None:
        self.error = error
        self.observation_space = _UnbuiltSpace(error)
        self.action_space = None

    def reset(self, **kwargs):
        raise self.error

    def step(self, action):
        raise self.error

    def render(self):
        raise self.error

    def close(self) -> None:
        pass


@dataclass(frozen=True)
class WorkerEnvFn:
    """``env_fn``, whose exception in a vector-env worker reaches the main process unchanged
    (at the first ``reset``), instead of a broken pipe; in the main process it just calls it."""

    env_fn: Callable[[], gym.Env]

    def __call__(self) -> gym.Env:
        if multiprocessing.parent_process() is None:
            return self.env_fn()
        try:
            return self.env_fn()
        except Exception as error:  # noqa: BLE001 - any: it is raised again where it is seen
            traceback.print_exc()  # where it happened, for envs whose error cannot be sent
            return _FailedEnv(error)


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
