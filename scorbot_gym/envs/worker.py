"""A vector-env worker that cannot build its env reports why, instead of a broken pipe.

Gymnasium's ``AsyncVectorEnv`` worker calls its env function before its error handling starts:
an exception there ends the worker, and the main process only sees ``ConnectionResetError`` or
``BrokenPipeError`` on its next call. Here such a worker is handed a stand-in env that raises
the original exception at its first use, which the worker does send back, so the main process
raises the real error (``KeyError: unknown object 'nope' ...``). Only in Gymnasium's workers
(told by their process name): stable-baselines3's ``SubprocVecEnv`` sends no worker errors back
at all, so there, as in any other process, the env function raises as it would.

- :class:`WorkerEnvFn` wraps any env function (``pin_env_fns`` and
  :class:`~scorbot_gym.envs.overlapped.OverlappedVectorEnv` use it):
  ``gymnasium.vector.AsyncVectorEnv([WorkerEnvFn(fn) for fn in env_fns])``;
- :func:`make_grasp_env`, the entry point of the registered ids, and
  :func:`~scorbot_gym.envs.factory.make_env` do the same, so
  ``AsyncVectorEnv([lambda: gym.make("scorbot_gym:ScorbotGrasp-v0", ...), ...])`` and
  ``AsyncVectorEnv([partial(make_env, pose="manifold", pose_kwargs={"models": path}), ...])``
  report it too (a bad model path, say).
"""

from __future__ import annotations

import functools
import multiprocessing
import signal
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.vector.async_vector_env import AsyncState

# How Gymnasium's AsyncVectorEnv names its worker processes ("Worker<AsyncVectorEnv>-0").
_GYMNASIUM_WORKER = "Worker<"


class _UnbuiltSpace(gym.spaces.Dict):
    """The observation space of an env that could not be built: comparing it raises the error.

    ``AsyncVectorEnv`` first asks each worker whether its spaces equal the main process's env's
    (``main_space == worker_space``). Python tries the right operand's ``__eq__`` first when
    its type subclasses the left's, so for a ``Dict`` observation space (every scorbot-gym env)
    this raises the worker's error there, inside the worker's error handling."""

    def __init__(self, error: Exception) -> None:
        super().__init__({"unbuilt": gym.spaces.Discrete(1)})  # gym.make's checker wants one
        self.error = error

    def __eq__(self, other: object) -> bool:
        raise self.error

    __hash__ = None


class _FailedEnv(gym.Env):
    """What a worker holds when its env could not be built: every use raises that error (an
    attribute it lacks too, so a wrapper built on it fails with the same error)."""

    def __init__(self, error: Exception, action_space: gym.Space | None = None) -> None:
        self.error = error
        self.observation_space = _UnbuiltSpace(error)
        self.action_space = action_space

    def __getattr__(self, name: str) -> Any:
        if name.startswith("_") or name == "error":  # pickling and copying probe these
            raise AttributeError(name)
        raise self.error

    def reset(self, **kwargs):
        raise self.error

    def step(self, action):
        raise self.error

    def render(self):
        raise self.error

    def close(self) -> None:
        pass


def _in_gymnasium_worker() -> bool:
    return multiprocessing.current_process().name.startswith(_GYMNASIUM_WORKER)


@dataclass(frozen=True)
class WorkerEnvFn:
    """``env_fn``, whose exception in a Gymnasium vector-env worker reaches the main process
    unchanged instead of a broken pipe; anywhere else it just calls ``env_fn``."""

    env_fn: Callable[[], gym.Env]

    def __call__(self) -> gym.Env:
        if not _in_gymnasium_worker():
            return self.env_fn()
        try:
            return self.env_fn()
        except Exception as error:  # noqa: BLE001 - any: it is raised again where it is seen
            traceback.print_exc()  # where it happened, for envs whose error cannot be sent
            return _FailedEnv(error)


def built_or_failed(build: Callable[[], gym.Env]) -> gym.Env:
    """``build()``; in a Gymnasium vector-env worker, a failure is handed back as a stand-in
    env that raises it (module docstring), with the action space every scorbot-gym env has
    (``gym.make``'s checker reads it)."""
    if not _in_gymnasium_worker():
        return build()
    try:
        return build()
    except Exception as error:  # noqa: BLE001 - raised again in the main process
        traceback.print_exc()
        return _FailedEnv(error, gym.spaces.Box(-1.0, 1.0, shape=(6,), dtype=np.float32))


def make_grasp_env(**kwargs: Any) -> gym.Env:
    """``ScorbotGraspEnv(**kwargs)``, the registered ids' entry point; in a Gymnasium vector-env
    worker, a failure is handed back as a stand-in env that raises it (module docstring)."""
    from scorbot_gym.envs.grasp import ScorbotGraspEnv

    return built_or_failed(lambda: ScorbotGraspEnv(**kwargs))


# What the main process's end of a pipe raises once the worker at the other end is gone.
_DEAD_PIPE = (BrokenPipeError, ConnectionResetError, EOFError)


class WatchedAsyncVectorEnv(gym.vector.AsyncVectorEnv):
    """Gymnasium's ``AsyncVectorEnv``, with a worker that died (killed, out of memory, a crash
    in C) reported in one line naming it and how it ended, instead of ``BrokenPipeError`` /
    ``ConnectionResetError`` from the pipe; every later call raises the same, and ``close``
    ends the other workers. A worker's Python errors reach the main process as themselves, as
    in ``AsyncVectorEnv`` (wrap env functions in :class:`WorkerEnvFn` for errors in building
    the env). :class:`~scorbot_gym.envs.overlapped.OverlappedVectorEnv` runs its workers in one.
    """

    _died: str | None = None
    #: added to a worker's index in messages (an env of a larger vector env, as in
    #: OverlappedVectorEnv, whose env 0 runs in the main process)
    env_index_offset = 0

    def _assert_is_running(self) -> None:
        super()._assert_is_running()
        if self._died is not None:
            raise RuntimeError(self._died)

    def _worker_died(self) -> RuntimeError:
        """The one-line error for a worker whose pipe broke (waits up to 2 s for it to end)."""
        deadline = time.monotonic() + 2.0
        while time.monotonic() < deadline:
            dead = [(i, p) for i, p in enumerate(self.processes) if not p.is_alive()]
            if dead:
                break
            time.sleep(0.02)
        if not dead:
            self._died = "a vector-env worker closed its pipe (it is still running)"
        else:
            i, process = dead[0]
            code = process.exitcode
            how = (
                f"killed by {signal.Signals(-code).name}"
                if code is not None and code < 0
                else f"exited with code {code}"
            )
            self._died = (
                f"the vector-env worker of env {i + self.env_index_offset} (pid {process.pid}) "
                f"died, {how}; its env is gone: close this vector env and make a new one"
            )
        self._state = AsyncState.DEFAULT
        return RuntimeError(self._died)

    def close_extras(self, timeout: float | None = None, terminate: bool = False) -> None:
        super().close_extras(timeout, terminate or self._died is not None)


def _reporting_dead_workers(name: str) -> Callable:
    method = getattr(gym.vector.AsyncVectorEnv, name)

    @functools.wraps(method)
    def watched(self: WatchedAsyncVectorEnv, *args: Any, **kwargs: Any) -> Any:
        try:
            return method(self, *args, **kwargs)
        except _DEAD_PIPE:
            raise self._worker_died() from None

    return watched


for _name in ("reset_async", "reset_wait", "step_async", "step_wait", "call_async", "call_wait",
              "set_attr"):  # fmt: skip
    setattr(WatchedAsyncVectorEnv, _name, _reporting_dead_workers(_name))
