"""Run seeded grasping episodes and summarize them (used by the CLI and the benchmarks)."""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass

import gymnasium as gym
import numpy as np
from tqdm import tqdm

from scorbot_gym.controllers import ScriptedGraspController
from scorbot_gym.objects import get_object
from scorbot_gym.perception import PerceivedPose, oracle_pose
from scorbot_gym.task import FAILURE_CAUSES

POLICIES = ("scripted", "random")
POSE_SOURCES = ("oracle", "manifold")
PoseFn = Callable[[gym.Env, dict], PerceivedPose]


@dataclass
class EpisodeResult:
    seed: int
    object_name: str
    success: bool
    steps: int
    failure_cause: str | None
    total_reward: float
    pose_valid: bool = True
    position_error_m: float | None = None
    rotation_error_deg: float | None = None


def run_episode(
    env: gym.Env,
    seed: int,
    policy: str = "scripted",
    object_name: str | None = None,
    pose_fn: PoseFn = oracle_pose,
    on_frame: Callable[[], None] | None = None,
) -> EpisodeResult:
    """One episode. ``pose_fn(env, info)`` gives the pose the scripted policy grasps at
    (default: the ground truth); without a valid pose the arm holds still, the gripper open,
    until the time limit. ``on_frame`` is called after reset and every step."""
    if policy not in POLICIES:
        raise ValueError(f"policy must be one of {POLICIES}, got {policy!r}")
    options = {"object_name": object_name} if object_name else None
    obs, info = env.reset(seed=seed, options=options)
    env.action_space.seed(seed)
    controller, perceived = None, None
    if policy == "scripted":
        perceived = pose_fn(env, info)
        if perceived.pose is not None:
            controller = ScriptedGraspController.for_env(env)
            spec = get_object(info["object_name"])
            controller.reset(perceived.pose, spec, env.unwrapped.sim.table_height)
    hold = np.r_[np.zeros(5), 1.0].astype(np.float32)
    if on_frame:
        on_frame()
    total, steps = 0.0, 0
    while True:
        if controller is not None:
            action = controller.act(obs)
        else:
            action = hold if policy == "scripted" else env.action_space.sample()
        obs, reward, terminated, truncated, info = env.step(action)
        total += float(reward)
        steps += 1
        if on_frame:
            on_frame()
        if terminated or truncated:
            break
    valid = perceived is None or perceived.pose is not None
    return EpisodeResult(
        seed,
        info["object_name"],
        bool(info["is_success"]),
        steps,
        info["failure_cause"],
        total,
        pose_valid=valid,
        position_error_m=perceived.position_error_m if perceived else None,
        rotation_error_deg=perceived.rotation_error_deg if perceived else None,
    )


def run_episodes(
    env: gym.Env,
    episodes: int,
    seed: int = 0,
    progress: bool = True,
    **kwargs,
) -> list[EpisodeResult]:
    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}")
    seeds: Iterable[int] = range(seed, seed + episodes)
    bar = tqdm(seeds, desc="episodes", unit="ep", disable=not progress, leave=False)
    return [run_episode(env, s, **kwargs) for s in bar]


def wilson_interval(successes: int, n: int, z: float = 1.959964) -> tuple[float, float]:
    """95 % Wilson score interval for a binomial proportion (sound at 0 % and 100 %)."""
    if n == 0:
        return (0.0, 1.0)
    p = successes / n
    denom = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    return (max(0.0, centre - half), min(1.0, centre + half))


def summarize(results: list[EpisodeResult]) -> dict:
    n = len(results)
    wins = [r for r in results if r.success]
    lo, hi = wilson_interval(len(wins), n)
    causes = Counter(r.failure_cause for r in results if not r.success)
    per_object: dict[str, dict] = {}
    for r in results:
        o = per_object.setdefault(r.object_name, {"episodes": 0, "successes": 0})
        o["episodes"] += 1
        o["successes"] += int(r.success)
    valid = [r for r in results if r.pose_valid and r.rotation_error_deg is not None]
    pose = {
        "valid_rate": sum(r.pose_valid for r in results) / n if n else 0.0,
        "median_position_error_mm": (
            1000 * float(np.median([r.position_error_m for r in valid])) if valid else None
        ),
        "median_rotation_error_deg": (
            float(np.median([r.rotation_error_deg for r in valid])) if valid else None
        ),
    }
    return {
        "episodes": n,
        "successes": len(wins),
        "success_rate": len(wins) / n if n else 0.0,
        "success_rate_ci95": [lo, hi],
        "mean_steps_to_success": float(np.mean([r.steps for r in wins])) if wins else None,
        "failure_causes": {c: causes.get(c, 0) for c in FAILURE_CAUSES},
        "per_object": per_object,
        "pose": pose,
        "results": [asdict(r) for r in results],
    }


def format_summary(summary: dict) -> str:
    lo, hi = summary["success_rate_ci95"]
    steps = summary["mean_steps_to_success"]
    rows = [
        ("episodes", f"{summary['episodes']}"),
        ("success rate", f"{summary['success_rate']:.1%}  (95% CI {lo:.1%} - {hi:.1%})"),
        ("mean steps to success", "-" if steps is None else f"{steps:.1f}"),
    ]
    rows += [(f"failures: {c}", str(k)) for c, k in summary["failure_causes"].items()]
    pose = summary["pose"]
    if pose["median_rotation_error_deg"] is not None:
        rows += [
            ("pose estimates valid", f"{pose['valid_rate']:.1%}"),
            ("median position error", f"{pose['median_position_error_mm']:.1f} mm"),
            ("median rotation error", f"{pose['median_rotation_error_deg']:.2f} deg"),
        ]
    rows += [
        (f"  {name}", f"{o['successes']}/{o['episodes']}")
        for name, o in sorted(summary["per_object"].items())
    ]
    width = max(len(r[0]) for r in rows)
    return "\n".join(f"{k:<{width}}  {v}" for k, v in rows)
