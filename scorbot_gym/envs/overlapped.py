"""A vector env whose calling process steps one of the envs while worker processes step the rest.

Gymnasium's ``AsyncVectorEnv`` sends every sub-env to a worker process and then waits: on a
machine with as many cores as envs the main process sits idle for the whole step, the workers
idle while it collects, and each vector step pays a full round trip before any env can start
the next one. Stepping env 0 in the calling process, between sending the others their actions
and collecting their results, puts that waiting time to work: N envs need N - 1 workers, and
the round trip overlaps with env 0's own step (``benchmarks/vector_env.py`` measures it against
``AsyncVectorEnv`` and against N independent processes).

The result is an ordinary Gymnasium ``VectorEnv``: batched observations and infos in env
order, seeds ``seed + i``, and the autoreset mode of ``AsyncVectorEnv`` (env 0 goes through a
one-env ``SyncVectorEnv``, which implements the same modes). The calling process now runs an
env, so what it renders runs on its cores: with software rendering set ``LP_NUM_THREADS=0``
before its first frame so that llvmpipe rasterizes in the stepping thread instead of starting a
thread per core that contends with the workers (worker processes do this by themselves).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode, SyncVectorEnv
from gymnasium.vector.utils import batch_space, create_empty_array

from scorbot_gym.envs.worker import WatchedAsyncVectorEnv, WorkerEnvFn


class OverlappedVectorEnv(gym.vector.VectorEnv):
    """``env_fns[0]`` runs in this process, ``env_fns[1:]`` in an ``AsyncVectorEnv`` (one that
    names a worker that died: :class:`~scorbot_gym.envs.worker.WatchedAsyncVectorEnv`).

    ``worker_kwargs`` go to that ``AsyncVectorEnv`` (``shared_memory``, ``context``,
    ``daemon``, ``max_concurrency``); ``autoreset_mode`` applies to every env. Observations
    come back as new arrays on every call (``AsyncVectorEnv``'s ``copy=True``).
    """

    def __init__(
        self,
        env_fns: Sequence[Callable[[], gym.Env]],
        *,
        autoreset_mode: str | AutoresetMode = AutoresetMode.NEXT_STEP,
        **worker_kwargs: Any,
    ) -> None:
        if len(env_fns) < 2:
            raise ValueError(
                f"OverlappedVectorEnv needs at least 2 env functions (one runs in this process, "
                f"the others in workers), got {len(env_fns)}; use SyncVectorEnv for one env"
            )
        unknown = set(worker_kwargs) - {"shared_memory", "context", "daemon", "max_concurrency"}
        if unknown:
            raise ValueError(
                f"unknown worker settings {sorted(unknown)}; valid: shared_memory, context, "
                "daemon, max_concurrency (observations are always returned as new arrays)"
            )
        self.autoreset_mode = AutoresetMode(autoreset_mode)
        # Workers first: a forked worker then inherits no env (and no GL context) from here.
        # Our concatenation copies the workers' observations out of shared memory.
        self.workers = WatchedAsyncVectorEnv(  # a dead worker is named, not a broken pipe
            [WorkerEnvFn(fn) for fn in env_fns[1:]],  # their errors reach us as themselves
            copy=False,
            autoreset_mode=self.autoreset_mode,
            **worker_kwargs,
        )
        self.workers.env_index_offset = 1  # its env i is our env i + 1
        try:
            self.local = SyncVectorEnv(env_fns[:1], copy=False, autoreset_mode=self.autoreset_mode)
        except BaseException:
            self.workers.close()
            raise
        self.num_envs = len(env_fns)
        self.metadata = dict(self.local.metadata)
        self.render_mode = self.local.render_mode
        self.spec = self.local.spec
        self.single_observation_space = self.local.single_observation_space
        self.single_action_space = self.local.single_action_space
        for what, here, there in (
            ("observation", self.single_observation_space, self.workers.single_observation_space),
            ("action", self.single_action_space, self.workers.single_action_space),
        ):
            if here != there:
                self.local.close()
                self.workers.close()
                raise ValueError(
                    f"the envs' {what} spaces differ: env 0 has {here}, the others {there}"
                )
        self._local_obs = create_empty_array(self.single_observation_space, 1)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)

    def reset(
        self,
        *,
        seed: int | list[int | None] | None = None,
        options: dict[str, Any] | None = None,
    ) -> tuple[Any, dict[str, Any]]:
        if seed is None:
            seeds: list[int | None] = [None] * self.num_envs
        elif isinstance(seed, int):
            seeds = [seed + i for i in range(self.num_envs)]
        else:
            seeds = list(seed)
            if len(seeds) != self.num_envs:
                raise ValueError(
                    f"seed is a list of {len(seeds)} seeds; it must have one per env "
                    f"(num_envs={self.num_envs})"
                )
        local_options, worker_options = _split_reset_mask(options, self.num_envs)
        reset_workers = _resets_any(worker_options)
        if reset_workers:
            self.workers.reset_async(seed=seeds[1:], options=worker_options)
        local_info: dict = {}
        if _resets_any(local_options):
            self._local_obs, local_info = self.local.reset(seed=seeds[:1], options=local_options)
        worker_obs, worker_info = (
            self.workers.reset_wait() if reset_workers else (self.workers.observations, {})
        )
        return (
            _concatenate(self._local_obs, worker_obs),
            _merge_infos(local_info, 1, worker_info, self.num_envs - 1),
        )

    def step(self, actions: Any) -> tuple[Any, np.ndarray, np.ndarray, np.ndarray, dict]:
        self.workers.step_async(_slice(actions, 1, None))
        try:
            obs0, rew0, term0, trunc0, info0 = self.local.step(_slice(actions, 0, 1))
        except BaseException:
            self.workers.step_wait()  # collect the workers' step: the env stays usable
            raise
        self._local_obs = obs0
        obs, rew, term, trunc, info = self.workers.step_wait()
        return (
            _concatenate(obs0, obs),
            np.concatenate([rew0, rew]),
            np.concatenate([term0, term]),
            np.concatenate([trunc0, trunc]),
            _merge_infos(info0, 1, info, self.num_envs - 1),
        )

    def call(self, name: str, *args: Any, **kwargs: Any) -> tuple[Any, ...]:
        self.workers.call_async(name, *args, **kwargs)
        first = self.local.call(name, *args, **kwargs)
        return first + self.workers.call_wait()

    def render(self) -> tuple[Any, ...] | None:
        return self.call("render")

    def get_attr(self, name: str) -> tuple[Any, ...]:
        return self.local.get_attr(name) + self.workers.get_attr(name)

    def set_attr(self, name: str, values: list[Any] | tuple[Any, ...] | object) -> None:
        if isinstance(values, (list, tuple)):
            if len(values) != self.num_envs:
                raise ValueError(
                    f"set_attr got {len(values)} values; give one per env "
                    f"(num_envs={self.num_envs}) or a single value for all"
                )
            self.local.set_attr(name, list(values[:1]))
            self.workers.set_attr(name, list(values[1:]))
        else:
            self.local.set_attr(name, values)
            self.workers.set_attr(name, values)

    @property
    def processes(self) -> list:
        """The worker processes (env 0 runs in this one)."""
        return self.workers.processes

    @property
    def np_random_seed(self) -> tuple[int, ...]:
        return self.local.np_random_seed + self.workers.np_random_seed

    def close_extras(self, **kwargs: Any) -> None:
        self.local.close()
        self.workers.close(**kwargs)


def _slice(batch: Any, start: int, stop: int | None) -> Any:
    """Envs ``start:stop`` of a batch of actions or observations (dicts and tuples nest)."""
    if isinstance(batch, dict):
        return {k: _slice(v, start, stop) for k, v in batch.items()}
    if isinstance(batch, tuple):
        return tuple(_slice(v, start, stop) for v in batch)
    return batch[start:stop]


def _concatenate(first: Any, rest: Any) -> Any:
    if isinstance(first, dict):
        return {k: _concatenate(first[k], rest[k]) for k in first}
    if isinstance(first, tuple):
        return tuple(_concatenate(a, b) for a, b in zip(first, rest, strict=True))
    return np.concatenate([first, rest])


def _split_reset_mask(options: dict | None, num_envs: int) -> tuple[dict | None, dict | None]:
    """``options`` for env 0 and for the workers: ``reset_mask`` split between them."""
    if options is None or "reset_mask" not in options:
        return options, options
    mask = options["reset_mask"]
    if not isinstance(mask, np.ndarray) or mask.dtype != np.bool_ or mask.shape != (num_envs,):
        raise ValueError(
            f"options['reset_mask'] must be a bool numpy array of shape ({num_envs},), got "
            f"{type(mask).__name__} {getattr(mask, 'dtype', '')} {getattr(mask, 'shape', '')}"
        )
    if not mask.any():
        raise ValueError("options['reset_mask'] resets no env; set at least one entry to True")
    return {**options, "reset_mask": mask[:1]}, {**options, "reset_mask": mask[1:]}


def _resets_any(options: dict | None) -> bool:
    return options is None or bool(np.any(options.get("reset_mask", True)))


def _merge_infos(first: dict, n_first: int, rest: dict, n_rest: int) -> dict:
    """Two vector infos (Gymnasium's layout: ``key`` holds one value per env, ``_key`` says
    which envs have it; dicts nest) joined in env order."""
    merged: dict = {}
    for key in {**first, **rest}:
        if key.startswith("_"):
            continue
        a, b = first.get(key), rest.get(key)
        if isinstance(a, dict) or isinstance(b, dict):
            merged[key] = _merge_infos(a or {}, n_first, b or {}, n_rest)
        else:
            merged[key] = np.concatenate([_values(a, n_first, b), _values(b, n_rest, a)])
        mask_a = first.get(f"_{key}", np.zeros(n_first, bool))
        mask_b = rest.get(f"_{key}", np.zeros(n_rest, bool))
        merged[f"_{key}"] = np.concatenate([mask_a, mask_b])
    return merged


def _values(values: np.ndarray | None, n: int, other: np.ndarray | None) -> np.ndarray:
    """``values``, or ``n`` empty entries shaped like ``other``'s (zeros, or ``None`` for
    objects) for the part of the batch where no env reported the key."""
    if values is not None:
        return values
    if other.dtype == object:
        return np.full(n, None, dtype=object)
    return np.zeros((n, *other.shape[1:]), dtype=other.dtype)
