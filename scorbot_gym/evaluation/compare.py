"""Scripted vs learned grasping, paired: the table (and plot) a paper would print.

Every arm (a policy under a pose condition) runs the same episode seeds ``seed ... seed+N-1``,
so the object, its placement and the pose noise draws are the same across arms and the arms
can be compared episode by episode. Per arm: success rate with a 95 % Wilson interval, steps to
success, failure causes, per-object success, the perception record. Per pair of policies under
one pose condition: the difference of success rates with Newcombe's 95 % interval for *paired*
proportions (method 10, Newcombe 1998, Stat. Med. 17:2635) and McNemar's exact test on the
discordant episodes.

Pose conditions: ``oracle``; ``noisy@S`` (``noisy_oracle`` with x-y position noise S metres and
heading noise ``S * DEG_PER_M`` degrees, i.e. 1 cm goes with 5 degrees); ``manifold`` (the
pose-manifold estimator from a ``scorbot-gym pose train`` model file, or without one the default
models of the top camera, trained on first use and cached, as ``scorbot-gym rollout`` uses).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from scorbot_gym.envs.factory import make_env
from scorbot_gym.evaluation.episodes import EpisodeResult, run_episodes
from scorbot_gym.evaluation.summary import newcombe_paired_diff, summarize, wilson_interval
from scorbot_gym.policies import RandomPolicy, ScriptedGraspPolicy
from scorbot_gym.policies.imitation import ImitationPolicy
from scorbot_gym.policies.sb3 import SB3Policy

DEG_PER_M = 500.0  # heading noise (deg) per metre of position noise in noisy@S conditions
BUILTIN_POLICIES = ("scripted", "random", "rl", "learned")


@dataclass(frozen=True)
class PoseCondition:
    label: str
    source: str
    kwargs: dict[str, Any]
    noise_m: float | None  # position noise (0 for the oracle; None when not a noise level)


def pose_conditions(
    poses: list[str], noise: list[float] = (), pose_model: str | Path | None = None
) -> list[PoseCondition]:
    """``oracle`` / ``noisy`` / ``manifold`` names, plus one ``noisy@S`` per noise level.

    ``manifold`` without ``pose_model`` gets its models (the defaults) from :func:`compare`."""
    out: list[PoseCondition] = []
    for p in poses:
        if p == "oracle":
            out.append(PoseCondition("oracle", "oracle", {}, 0.0))
        elif p == "manifold":
            kw = {} if pose_model is None else {"models": str(pose_model)}
            out.append(PoseCondition("manifold", "manifold", kw, None))
        elif p == "noisy":
            noise = list(noise) or [0.01]
        else:
            raise ValueError(f"unknown pose condition {p!r}; valid: oracle, noisy, manifold")
    for s in noise:
        if not (np.isfinite(s) and s >= 0):
            raise ValueError(f"noise levels are position std devs in metres >= 0, got {s}")
        kw = {"pos_sigma_m": float(s), "yaw_sigma_deg": float(s) * DEG_PER_M}
        out.append(PoseCondition(f"noisy@{s:g}", "noisy_oracle", kw, float(s)))
    if not out:
        raise ValueError("give at least one pose condition")
    return out


def policy_label(policy: str) -> str:
    """``scripted``, ``rl``, or a policy directory's run name (``runs/bc/policy`` -> ``bc``)."""
    p = Path(policy)
    return p.parent.name if p.name == "policy" else p.name


def load_policy(name: str) -> SB3Policy | ImitationPolicy | None:
    """``rl`` (the shipped residual), ``learned`` (the shipped stand-alone imitation policy) or
    a policy directory; ``None`` for scripted/random."""
    if name in ("scripted", "random"):
        return None
    from scorbot_gym.policies.loading import load_policy as load_saved

    return load_saved(name)


def _make_policy(name: str, learned: SB3Policy | None, env, seed: int):
    if name == "scripted":
        return ScriptedGraspPolicy.for_env(env)
    if name == "random":
        return RandomPolicy(env.action_space, seed)
    return learned.bind(env)


def _record(policy: str, cond: PoseCondition, results: list[EpisodeResult], learned) -> dict:
    s = summarize(results)
    wins = [r.steps for r in results if r.success]
    per_object = {
        k: {**v, "success_rate": v["successes"] / v["episodes"]}
        for k, v in sorted(s["per_object"].items())
    }
    return {
        "policy": policy,
        "pose": cond.label,
        "pose_source": cond.source,
        "noise_pos_m": cond.noise_m,
        "episodes": s["episodes"],
        "successes": s["successes"],
        "success_rate": s["success_rate"],
        "ci95": s["success_rate_ci95"],
        "median_steps_to_success": float(np.median(wins)) if wins else None,
        "mean_steps_to_success": s["mean_steps_to_success"],
        "failure_causes": s["failure_causes"],
        "per_object": per_object,
        "perception": s["perception"],
        "saw_scripted_controller": (
            learned.meta.get("saw_scripted_controller") if learned is not None else None
        ),
        "episode_success": [bool(r.success) for r in results],
    }


def compare(
    policies: list[str],
    poses: list[str],
    episodes: int,
    seed: int = 0,
    noise: list[float] = (),
    pose_model: str | Path | None = None,
    objects: list[str] | None = None,
    action_type: str = "cartesian",
    estimate_every: int = 1,
    progress: bool = True,
) -> dict[str, Any]:
    """Run every policy under every pose condition on the same seeds; returns the report
    (``results``: one record per arm; ``differences``: each policy minus the first)."""
    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}")
    if not policies:
        raise ValueError("give at least one policy (scripted, random, rl or a policy directory)")
    conds = pose_conditions(poses, noise, pose_model)
    learned = {p: load_policy(p) for p in policies}
    if any(c.source == "manifold" and "models" not in c.kwargs for c in conds):
        from scorbot_gym.perception.training import default_pose_models

        models = default_pose_models(progress=progress)  # once, for every arm
        conds = [
            PoseCondition(c.label, c.source, {"models": models}, c.noise_m)
            if c.source == "manifold" and "models" not in c.kwargs
            else c
            for c in conds
        ]
    results, diffs = [], []
    for cond in conds:
        arm_records = []
        for name in policies:
            pol = learned[name]
            kw = pol.env_kwargs() if pol is not None else {}
            env_id = kw.pop("env_id", None) or (
                "ScorbotGraspCartesian-v0" if action_type == "cartesian" else "ScorbotGrasp-v0"
            )
            env = make_env(
                env_id,
                pose=cond.source,
                pose_kwargs=cond.kwargs,
                estimate_every=estimate_every,
                objects=objects,
                **kw,
            )
            try:
                policy = _make_policy(name, pol, env, seed)
                eps = run_episodes(env, policy, episodes, seed, progress=progress)
            finally:
                env.close()
            arm_records.append(_record(name, cond, eps, pol))
        ref = arm_records[0]
        for rec in arm_records[1:]:
            d = newcombe_paired_diff(rec["episode_success"], ref["episode_success"])
            diffs.append({"pose": cond.label, "a": rec["policy"], "b": ref["policy"], **d})
        results += arm_records
    return {
        "seeds": [seed, seed + episodes - 1],
        "episodes": episodes,
        "objects": objects,
        "action_type": action_type,
        "estimate_every": estimate_every,
        "difference_method": "Newcombe (1998) method 10 paired-proportion interval; McNemar "
        "exact test",
        "noise_heading_deg_per_m": DEG_PER_M,
        "results": results,
        "differences": diffs,
    }


def plot_comparison(report: dict[str, Any], path: str | Path) -> None:
    """Success per object (bars with Wilson 95 % intervals, one per arm) and success against
    pose-noise level (one line per policy; the oracle is noise 0)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pose.fileio import atomic_write_bytes

    res = report["results"]
    objects = sorted({o for r in res for o in r["per_object"]})
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(13, 4.5), gridspec_kw={"width_ratios": [2, 1]})
    width = 0.8 / max(1, len(res))
    for i, r in enumerate(res):
        rates, errs = [], [[], []]
        for o in objects:
            v = r["per_object"].get(o, {"successes": 0, "episodes": 0})
            p = v["successes"] / v["episodes"] if v["episodes"] else np.nan
            lo, hi = wilson_interval(v["successes"], v["episodes"])
            rates.append(p)
            errs[0].append(max(0.0, p - lo) if v["episodes"] else 0.0)
            errs[1].append(max(0.0, hi - p) if v["episodes"] else 0.0)
        x = np.arange(len(objects)) + (i - (len(res) - 1) / 2) * width
        ax1.bar(
            x,
            rates,
            width,
            yerr=errs,
            capsize=2,
            label=f"{policy_label(r['policy'])} / {r['pose']}",
        )
    ax1.set_xticks(np.arange(len(objects)), objects, rotation=30, ha="right")
    ax1.set_ylim(0, 1.05)
    ax1.set_ylabel("success rate")
    counts = sorted({r["episodes"] for r in res})
    ax1.set_title(f"success per object ({'/'.join(map(str, counts))} paired episodes per arm)")
    ax1.legend(fontsize=7)
    for name in dict.fromkeys(r["policy"] for r in res):
        pts = sorted(
            (r["noise_pos_m"], r["success_rate"], r["ci95"])
            for r in res
            if r["policy"] == name and r["noise_pos_m"] is not None
        )
        if pts:
            xs = [100 * p[0] for p in pts]
            ys = [p[1] for p in pts]
            yerr = [[y - p[2][0] for y, p in zip(ys, pts, strict=True)]]
            yerr.append([p[2][1] - y for y, p in zip(ys, pts, strict=True)])
            ax2.errorbar(xs, ys, yerr=yerr, marker="o", capsize=3, label=policy_label(name))
    ax2.set_xlabel(f"pose noise: position std (cm); heading std = {DEG_PER_M / 100:g} deg per cm")
    ax2.set_ylabel("success rate")
    ax2.set_ylim(0, 1.05)
    ax2.set_title("success vs pose noise (0 = oracle)")
    ax2.legend(fontsize=8)
    fig.tight_layout()
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())
