"""Run seeded grasping episodes and summarize them (used by the CLI and the benchmarks)."""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass

import gymnasium as gym
import numpy as np
from tqdm import tqdm

from scorbot_gym.controllers import ObjectPose2D, ScriptedGraspController
from scorbot_gym.objects import get_object
from scorbot_gym.task import FAILURE_CAUSES

POLICIES = ("scripted", "random")
POSE_SOURCES = ("oracle",)


@dataclass
class EpisodeResult:
    seed: int
    object_name: str
    success: bool
    steps: int
    failure_cause: str | None
    total_reward: float


def yaw_from_quat(q: np.ndarray) -> float:
    """Heading about world z of a (w, x, y, z) quaternion."""
    w, x, y, z = q
    return float(np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))


def oracle_pose(info: dict) -> ObjectPose2D:
    pose = info["object_pose"]
    return ObjectPose2D(np.asarray(pose["position"]), yaw_from_quat(pose["quaternion"]))


def run_episode(
    env: gym.Env,
    seed: int,
    policy: str = "scripted",
    object_name: str | None = None,
    pose_fn: Callable[[dict, dict], ObjectPose2D] | None = None,
    on_frame: Callable[[], None] | None = None,
) -> EpisodeResult:
    """One episode. ``pose_fn(obs, info)`` gives the pose the scripted policy grasps at
    (default: the ground truth); ``on_frame`` is called after reset and every step."""
    if policy not in POLICIES:
        raise ValueError(f"policy must be one of {POLICIES}, got {policy!r}")
    options = {"object_name": object_name} if object_name else None
    obs, info = env.reset(seed=seed, options=options)
    env.action_space.seed(seed)
    controller = None
    if policy == "scripted":
        controller = ScriptedGraspController.for_env(env)
        pose = (pose_fn or (lambda _obs, i: oracle_pose(i)))(obs, info)
        spec = get_object(info["object_name"])
        controller.reset(pose, spec, env.unwrapped.sim.table_height)
    if on_frame:
        on_frame()
    total, steps = 0.0, 0
    while True:
        action = controller.act(obs) if controller else env.action_space.sample()
        obs, reward, terminated, truncated, info = env.step(action)
        total += float(reward)
        steps += 1
        if on_frame:
            on_frame()
        if terminated or truncated:
            break
    return EpisodeResult(
        seed, info["object_name"], bool(info["is_success"]), steps, info["failure_cause"], total
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
    return {
        "episodes": n,
        "successes": len(wins),
        "success_rate": len(wins) / n if n else 0.0,
        "success_rate_ci95": [lo, hi],
        "mean_steps_to_success": float(np.mean([r.steps for r in wins])) if wins else None,
        "failure_causes": {c: causes.get(c, 0) for c in FAILURE_CAUSES},
        "per_object": per_object,
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
    rows += [
        (f"  {name}", f"{o['successes']}/{o['episodes']}")
        for name, o in sorted(summary["per_object"].items())
    ]
    width = max(len(r[0]) for r in rows)
    return "\n".join(f"{k:<{width}}  {v}" for k, v in rows)
