"""Run seeded episodes of a policy on an env and record what happened (CLI and benchmarks).

``run_episode(env, policy, seed)`` is the one loop: reset with the seed, ``policy.reset(obs,
info)``, then ``policy.act(obs)`` until the episode ends. Whatever the env's wrappers put in
``info["perception"]`` (errors against the ground truth, recognition), with the wrapper's
wall-clock ``perception_timings``, is collected for the record; the policy never sees it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np
from tqdm import tqdm

from scorbot_gym.policies.base import Policy


@dataclass
class EpisodeResult:
    seed: int
    object_name: str
    success: bool
    steps: int
    failure_cause: str | None
    total_reward: float
    perception: dict[str, Any] | None = None  # per-episode perception record (see below)
    extra: dict[str, Any] = field(default_factory=dict)


def _perception_record(records: list[dict[str, Any]]) -> dict[str, Any] | None:
    """Aggregate the steps at which the pose source ran (``info["perception"]["estimated"]``)."""
    ran = [r for r in records if r.get("estimated")]
    if not ran:
        return None
    valid = [r for r in ran if r.get("valid")]

    def median(key: str, rows: list[dict]) -> float | None:
        vals = [r[key] for r in rows if r.get(key) is not None and np.isfinite(r[key])]
        return float(np.median(vals)) if vals else None

    recog = [r for r in ran if r.get("recognised") is not None]
    first = ran[0]
    clear = [r for r in ran if r.get("clear_view")]
    return {
        "estimates": len(ran),
        "valid": len(valid),
        "clear_view_estimates": len(clear),
        "clear_view_valid": sum(1 for r in clear if r.get("valid")),
        "first_valid": bool(first.get("valid")),
        "median_rot_err_deg": median("rot_err_deg", valid),
        "median_pos_err_cm": median("pos_err_cm", valid),
        "median_add_s_cm": median("add_s_cm", valid),
        "success_5deg": float(np.mean([bool(r["success_5deg"]) for r in valid])) if valid else None,
        "recognised": recog[-1]["recognised"] if recog else None,
        "true_class": first.get("true_class"),
        "recognition_correct": (
            float(np.mean([r["recognised"] == r["true_class"] for r in recog])) if recog else None
        ),
        "median_estimate_ms": median("total_ms", ran),
        "median_stage_ms": {
            k: float(np.median([r["timings_ms"][k] for r in ran if k in r.get("timings_ms", {})]))
            for k in sorted({k for r in ran for k in r.get("timings_ms", {})})
        },
        "privileged": bool(first.get("privileged")),
        **_clutter_record(ran),
    }


def _clutter_record(ran: list[dict[str, Any]]) -> dict[str, Any]:
    """On a cluttered table: how often the blob taken for the target was the target, and the
    recognition of the blobs of the first view (``info["perception"]["objects"]`` at reset,
    before the arm moves in and splits or hides them)."""
    if not any("objects" in r for r in ran):
        return {}  # not a source that splits a cluttered table
    picks = [r["target_recognised"] for r in ran if r.get("target_recognised") is not None]
    view = next((r for r in ran if r.get("objects")), {})
    blobs = [b for b in view.get("objects", []) if b.get("recognised") is not None]
    out = {
        "target_recognised_rate": float(np.mean(picks)) if picks else 0.0,  # never found: 0
        "blob_recognition_correct": (
            float(np.mean([b["recognised"] == b["true_class"] for b in blobs])) if blobs else None
        ),
    }
    if view.get("n_components") is not None:  # blobs before and after splitting, first view
        keys = ("objects", "components", "blobs")
        out["first_view_blobs"] = {k: view.get(f"n_{k}") for k in keys}
    return out


def _perception(env: gym.Env, info: dict) -> dict[str, Any]:
    """This step's ``info["perception"]`` with the pose wrapper's timings (kept out of ``info``
    so that a seeded episode's info is reproducible)."""
    try:
        timings = env.get_wrapper_attr("perception_timings")
    except AttributeError:
        timings = None
    return {**info["perception"], **timings} if timings else info["perception"]


def run_episode(
    env: gym.Env,
    policy: Policy,
    seed: int,
    options: dict[str, Any] | None = None,
    on_step: Callable[[dict, dict], None] | None = None,
) -> EpisodeResult:
    """One seeded episode of ``policy`` on ``env``. ``on_step(obs, info)`` is called after the
    reset and after every step (e.g. to grab video frames)."""
    obs, info = env.reset(seed=seed, options=options)
    seed_fn = getattr(policy, "seed", None)
    if callable(seed_fn):
        seed_fn(seed)
    policy.reset(obs, info)
    base = env.unwrapped
    cameras = tuple(getattr(base, "cameras", ()))
    visibility = getattr(base, "object_visibility", None) if cameras else None

    def record(info: dict) -> dict:
        """The step's perception record, with whether every camera saw the object unhidden
        (ground truth for the summary: estimates with a clear view)."""
        rec = _perception(env, info)
        if visibility is not None and rec.get("estimated"):
            rec["clear_view"] = all(visibility(c) >= 1.0 for c in cameras)
        return rec

    records = [record(info)] if "perception" in info else []
    if on_step:
        on_step(obs, info)
    total, steps = 0.0, 0
    closest = info.get("grasp_distance", math.inf)
    while True:
        obs, reward, terminated, truncated, info = env.step(policy.act(obs))
        total += float(reward)
        steps += 1
        if "perception" in info:
            records.append(record(info))
        closest = min(closest, info.get("grasp_distance", math.inf))
        if on_step:
            on_step(obs, info)
        if terminated or truncated:
            break
    extra = {"replans": policy.replans} if hasattr(policy, "replans") else {}
    if "grasp_distance" in info:  # where the hand ended, and came closest (ground truth)
        extra["final_grasp_distance_m"] = round(float(info["grasp_distance"]), 5)
        extra["closest_grasp_distance_m"] = round(float(closest), 5)
    if getattr(policy, "regrasps", 0):  # the scripted controller's retries after a miss
        extra["regrasps"] = int(policy.regrasp_count)
    if "distractors_knocked_over" in info:  # a table with distractors
        extra["distractors_knocked_over"] = int(info["distractors_knocked_over"])
    return EpisodeResult(
        seed,
        info["object_name"],
        bool(info["is_success"]),
        steps,
        info["failure_cause"],
        total,
        _perception_record(records),
        extra,
    )


def run_episodes(
    env: gym.Env,
    policy: Policy,
    episodes: int,
    seed: int = 0,
    options: dict[str, Any] | None = None,
    progress: bool = True,
) -> list[EpisodeResult]:
    """Episodes with seeds ``seed, seed + 1, ...`` (the same seeds for every policy compared)."""
    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}")
    seeds: Iterable[int] = range(seed, seed + episodes)
    bar = tqdm(seeds, desc="episodes", unit="ep", disable=not progress, leave=False)
    return [run_episode(env, policy, s, options) for s in bar]
