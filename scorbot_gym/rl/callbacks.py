"""Training callbacks: success-rate evaluation on held-out seeds, and atomic checkpoints.

Both keep their state in the run directory, so an interrupted run resumes with its learning
curve intact (``state.json`` holds the evaluation history and the training wall time so far).
Each evaluation is dumped to the logger (TensorBoard) at once, as SB3's ``EvalCallback`` does:
otherwise the last ones would wait for a log dump that never comes; and the whole history is
written to ``evaluations.npz`` in the format of SB3's ``EvalCallback`` (see
:func:`write_evaluations`), which RL Zoo's plotting scripts read.
"""

from __future__ import annotations

import io
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from pose.fileio import atomic_write_bytes, remove_orphaned_tmp
from scorbot_gym.evaluation.episodes import run_episodes
from scorbot_gym.evaluation.summary import summarize


class TrainingClock:
    """Training wall time, cumulative over resumed runs, not counting evaluations."""

    def __init__(self, offset_s: float = 0.0) -> None:
        self.offset_s, self._t0, self._paused = offset_s, time.perf_counter(), 0.0

    def pause(self) -> Callable[[], None]:
        t = time.perf_counter()

        def resume() -> None:
            self._paused += time.perf_counter() - t

        return resume

    @property
    def seconds(self) -> float:
        return self.offset_s + time.perf_counter() - self._t0 - self._paused


class SuccessEvalCallback(BaseCallback):
    """Every ``every`` env steps (and before the first update), run ``episodes`` deterministic
    episodes with seeds ``seed, seed + 1, ...`` (never used for training) through the same
    :func:`~scorbot_gym.evaluation.run_episode` loop as the comparison, and log the success
    rate (``eval/success_rate``, from ``info["is_success"]``) with its Wilson interval.

    ``make_policy(model)`` builds the :class:`~scorbot_gym.policies.sb3.SB3Policy` to evaluate
    (with the current normalisation statistics); ``env`` is a plain ``make_env`` env.
    ``on_best(model, record)`` is called after an evaluation at least as good as every earlier
    one (the latest among equals: it has trained longest), e.g. to export the best policy.
    With ``npz_path``, the history is written there after every evaluation
    (:func:`write_evaluations`).
    """

    def __init__(
        self,
        env,
        make_policy: Callable[[Any], Any],
        history: list[dict],
        clock: TrainingClock,
        every: int,
        episodes: int,
        seed: int,
        on_best: Callable[[Any, dict], None] | None = None,
        npz_path: Path | None = None,
    ) -> None:
        super().__init__()
        if every < 1 or episodes < 1:
            raise ValueError(f"every and episodes must be >= 1, got {every} and {episodes}")
        self.env, self.make_policy, self.history, self.clock = env, make_policy, history, clock
        self.every, self.episodes, self.seed, self.on_best = every, episodes, seed, on_best
        self.npz_path = npz_path
        self._next = 0

    def _on_training_start(self) -> None:
        done = self.history[-1]["timesteps"] if self.history else -1
        self._next = (done // self.every + 1) * self.every if done >= 0 else 0
        if self.num_timesteps >= self._next:
            self.evaluate()

    def _on_step(self) -> bool:
        if self.num_timesteps >= self._next:
            self.evaluate()
        return True

    def evaluate(self) -> dict:
        resume = self.clock.pause()
        results = run_episodes(
            self.env, self.make_policy(self.model), self.episodes, self.seed, progress=False
        )
        resume()
        s = summarize(results)
        rec = {
            "timesteps": int(self.num_timesteps),
            "wall_s": round(self.clock.seconds, 2),
            "episodes": s["episodes"],
            "success_rate": s["success_rate"],
            "ci95": s["success_rate_ci95"],
            # undiscounted, in the run's own reward (its reward_type)
            "mean_return": sum(r.total_reward for r in results) / len(results),
            "mean_steps_to_success": s["mean_steps_to_success"],
            "failure_causes": s["failure_causes"],
            # where the failed episodes' hands ended and came closest to the grasp point (m,
            # median): a policy that stalls short of the object shows here first
            **_failed_distances(results),
            # per episode, for evaluations.npz
            "returns": [round(float(r.total_reward), 6) for r in results],
            "lengths": [int(r.steps) for r in results],
            "successes": [bool(r.success) for r in results],
        }
        best = max((e["success_rate"] for e in self.history), default=-1.0)
        self.history.append(rec)
        if self.npz_path is not None:
            write_evaluations(self.npz_path, self.history)
        self.logger.record("eval/success_rate", rec["success_rate"])
        self.logger.record("eval/mean_reward", rec["mean_return"])  # SB3 EvalCallback's name
        self.logger.record("eval/wall_s", rec["wall_s"])
        self.logger.record("time/total_timesteps", rec["timesteps"], exclude="tensorboard")
        self.logger.dump(self.num_timesteps)
        if self.on_best is not None and rec["success_rate"] >= best:
            self.on_best(self.model, rec)
        self._next = (self.num_timesteps // self.every + 1) * self.every
        return rec


def _failed_distances(results: list) -> dict[str, float | None]:
    failed = [r.extra for r in results if not r.success and "final_grasp_distance_m" in r.extra]
    out: dict[str, float | None] = {}
    for key in ("final_grasp_distance_m", "closest_grasp_distance_m"):
        values = [e[key] for e in failed]
        out[f"failed_median_{key}"] = round(float(np.median(values)), 4) if values else None
    return out


def write_evaluations(path: Path, history: list[dict]) -> None:
    """``history`` as SB3's ``EvalCallback`` writes ``evaluations.npz`` (atomically):
    ``timesteps`` (n,), ``results`` (n, episodes) episode returns, ``ep_lengths`` (n, episodes)
    and ``successes`` (n, episodes). Records without per-episode data (written before this
    file existed) are left out. When the number of episodes changed between evaluations
    (``eval_episodes`` changed on resume) the shorter rows are padded with NaN (``results``,
    ``ep_lengths``, ``successes`` then floats): use ``np.nanmean``."""
    rows = [r for r in history if "returns" in r]
    width = max((len(r["returns"]) for r in rows), default=0)
    ragged = any(len(r["returns"]) != width for r in rows)

    def table(key: str, dtype) -> np.ndarray:
        if not ragged:
            return np.array([r[key] for r in rows], dtype).reshape(len(rows), width)
        out = np.full((len(rows), width), np.nan)
        for i, r in enumerate(rows):
            out[i, : len(r[key])] = r[key]
        return out

    buf = io.BytesIO()
    np.savez(
        buf,
        timesteps=np.array([r["timesteps"] for r in rows], np.int64),
        results=table("returns", np.float64),
        ep_lengths=table("lengths", np.int64),
        successes=table("successes", bool),
    )
    atomic_write_bytes(path, buf.getvalue())


class CheckpointCallback(BaseCallback):
    """Every ``every`` env steps, ``save(model)`` (which writes each file atomically)."""

    def __init__(self, save: Callable[[Any], None], every: int) -> None:
        super().__init__()
        if every < 1:
            raise ValueError(f"checkpoint interval must be >= 1 env steps, got {every}")
        self.save, self.every = save, every
        self._last = 0

    def _on_training_start(self) -> None:
        self._last = self.num_timesteps

    def _on_step(self) -> bool:
        if self.num_timesteps - self._last >= self.every:
            self.save(self.model)
            self._last = self.num_timesteps
        return True


def atomic_save(path: Path, write: Callable[[Path], None]) -> None:
    """``write(tmp)`` then ``os.replace(tmp, path)``: a reader never sees half a file."""
    path = Path(path)
    if path.parent.is_dir():
        remove_orphaned_tmp(path.parent)  # left by a killed run of this folder
    tmp = path.with_name(f".{path.stem}.tmp{os.getpid()}{path.suffix}")
    try:
        write(tmp)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
