"""Summaries of episode results: success with a 95 % interval, failure causes, per object, and
the perception record (validity, errors, recognition, estimator time)."""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import asdict
from typing import Any

import numpy as np

from scorbot_gym.evaluation.episodes import EpisodeResult
from scorbot_gym.tasks import FAILURE_CAUSES


def wilson_interval(successes: int, n: int, z: float = 1.959964) -> tuple[float, float]:
    """95 % Wilson score interval for a binomial proportion (sound at 0 % and 100 %)."""
    if n == 0:
        return (0.0, 1.0)
    p = successes / n
    denom = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    # the interval always holds p; rounding can put a bound a hair inside it at 0 % or 100 %
    return (min(p, max(0.0, centre - half)), max(p, min(1.0, centre + half)))


def _median(values) -> float | None:
    vals = [v for v in values if v is not None and np.isfinite(v)]
    return float(np.median(vals)) if vals else None


def perception_summary(results: list[EpisodeResult]) -> dict | None:
    """Pooled over episodes: the share of valid estimates, the share of episodes whose kept
    class is right, and medians over episodes of each episode's median error and time."""
    recs = [r.perception for r in results if r.perception is not None]
    if not recs:
        return None
    n_est = sum(p["estimates"] for p in recs)
    n_clear = sum(p.get("clear_view_estimates", 0) for p in recs)
    recog = [p for p in recs if p["recognised"] is not None]
    return {
        "estimates": n_est,
        "valid_rate": sum(p["valid"] for p in recs) / n_est if n_est else 0.0,
        "clear_view_estimates": n_clear,
        "clear_view_valid_rate": (
            sum(p.get("clear_view_valid", 0) for p in recs) / n_clear if n_clear else None
        ),
        "first_estimate_valid_rate": float(np.mean([p["first_valid"] for p in recs])),
        "recognition_accuracy": (
            float(np.mean([p["recognised"] == p["true_class"] for p in recog])) if recog else None
        ),
        "median_rot_err_deg": _median(p["median_rot_err_deg"] for p in recs),
        "median_pos_err_cm": _median(p["median_pos_err_cm"] for p in recs),
        "median_add_s_cm": _median(p["median_add_s_cm"] for p in recs),
        "median_estimate_ms": _median(p["median_estimate_ms"] for p in recs),
        "median_stage_ms": {
            k: _median(p["median_stage_ms"].get(k) for p in recs)
            for k in sorted({k for p in recs for k in p["median_stage_ms"]})
        },
        "privileged": any(p["privileged"] for p in recs),
        **_clutter_summary(recs),
    }


def _clutter_summary(recs: list[dict]) -> dict:
    """On cluttered tables: the share of episodes whose estimates mostly took the target's
    blob for the target, and the mean share of right blob recognitions in the first view."""
    rates = [p["target_recognised_rate"] for p in recs if "target_recognised_rate" in p]
    if not rates:
        return {}
    blobs = [p.get("blob_recognition_correct") for p in recs]
    blobs = [b for b in blobs if b is not None]
    out = {
        "target_recognition_accuracy": float(np.mean([r > 0.5 for r in rates])),
        "blob_recognition_accuracy": float(np.mean(blobs)) if blobs else None,
    }
    views = [p["first_view_blobs"] for p in recs if p.get("first_view_blobs")]
    if views:  # how often objects shared a blob in the first view, and how often it was split
        out["first_view_blobs"] = {
            "episodes": len(views),
            "fewer_components_than_objects": float(
                np.mean([v["components"] < v["objects"] for v in views])
            ),
            "split": float(np.mean([v["blobs"] > v["components"] for v in views])),
            "mean_components": float(np.mean([v["components"] for v in views])),
            "mean_blobs": float(np.mean([v["blobs"] for v in views])),
        }
    return out


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
    summary = {
        "episodes": n,
        "successes": len(wins),
        "success_rate": len(wins) / n if n else 0.0,
        "success_rate_ci95": [lo, hi],
        "mean_steps_to_success": float(np.mean([r.steps for r in wins])) if wins else None,
        "failure_causes": {c: causes.get(c, 0) for c in FAILURE_CAUSES},
        "per_object": per_object,
        "perception": perception_summary(results),
        "results": [asdict(r) for r in results],
    }
    if any("distractors_knocked_over" in r.extra for r in results):
        summary["distractors_knocked_over"] = sum(
            r.extra.get("distractors_knocked_over", 0) for r in results
        )
    if any("regrasps" in r.extra for r in results):  # episodes that retried, and won by it
        tried = [r for r in results if r.extra.get("regrasps", 0) > 0]
        summary["regrasps"] = {
            "episodes": len(tried),
            "successes": sum(r.success for r in tried),
        }
    return summary


def format_summary(summary: dict) -> str:
    lo, hi = summary["success_rate_ci95"]
    steps = summary["mean_steps_to_success"]
    rows = [
        ("episodes", f"{summary['episodes']}"),
        ("success rate", f"{summary['success_rate']:.1%}  (95% CI {lo:.1%} - {hi:.1%})"),
        ("mean steps to success", "-" if steps is None else f"{steps:.1f}"),
    ]
    rows += [(f"failures: {c}", str(k)) for c, k in summary["failure_causes"].items()]
    if "distractors_knocked_over" in summary:
        rows.append(("distractors knocked over", str(summary["distractors_knocked_over"])))
    if "regrasps" in summary:
        g = summary["regrasps"]
        rows.append(("re-grasps (won)", f"{g['episodes']} ({g['successes']})"))
    p = summary.get("perception")
    if p is not None:

        def fmt(v, spec: str, unit: str = "") -> str:
            return "-" if v is None else f"{v:{spec}}{unit}"

        clear = p.get("clear_view_valid_rate")
        rows += [
            (
                "pose estimates valid",
                f"{p['valid_rate']:.1%}  of {p['estimates']} estimates, one per estimating step "
                "(the arm hides the object for much of the grasp)",
            ),
            (
                "  with a clear view",
                "-"
                if clear is None
                else f"{clear:.1%}  of the {p['clear_view_estimates']} estimates made while "
                "nothing hid the object from the cameras",
            ),
            ("recognition accuracy", fmt(p["recognition_accuracy"], ".1%")),
            ("median position error", fmt(p["median_pos_err_cm"], ".2f", " cm")),
            ("median rotation error", fmt(p["median_rot_err_deg"], ".2f", " deg")),
            ("median estimator time", fmt(p["median_estimate_ms"], ".1f", " ms")),
        ]
        if p["privileged"]:
            rows.append(("pose source", "privileged (reads the ground truth)"))
    config = summary.get("config") or {}
    if config.get("pose") == "manifold" and config.get("recognize") is False:
        rows.append(("identity", "given: privileged, the estimator is told the true class"))
    rows += [
        (f"  {name}", f"{o['successes']}/{o['episodes']}")
        for name, o in sorted(summary["per_object"].items())
    ]
    width = max(len(r[0]) for r in rows)
    return "\n".join(f"{k:<{width}}  {v}" for k, v in rows)


def holm_adjusted(pvalues) -> list[float]:
    """Holm's step-down adjustment of ``pvalues`` for testing them as one family: the
    family-wise error stays at most alpha under any dependence between the tests (Bonferroni's
    guarantee, uniformly more powerful). A sweep compares one estimator with every other at
    every level, hundreds of tests, so an unadjusted p < 0.05 is expected by chance alone."""
    p = np.asarray(pvalues, float).ravel()
    if np.any(~np.isfinite(p)) or np.any((p < 0) | (p > 1)):
        raise ValueError(f"p-values must be in [0, 1], got {p.tolist()}")
    m = p.size
    adjusted = np.empty(m)
    running = 0.0
    for rank, i in enumerate(np.argsort(p, kind="stable")):
        running = max(running, (m - rank) * p[i])  # monotone in the sorted order
        adjusted[i] = min(1.0, running)
    return adjusted.tolist()


def newcombe_paired_diff(a: list[bool], b: list[bool]) -> dict[str, Any]:
    """Success-rate difference ``a - b`` over paired episodes, its 95 % interval (Newcombe
    method 10) and McNemar's exact two-sided p-value on the discordant pairs."""
    from scipy.stats import binomtest

    x, y = np.asarray(a, bool), np.asarray(b, bool)
    n = len(x)
    both, only_a = int(np.sum(x & y)), int(np.sum(x & ~y))
    only_b, neither = int(np.sum(~x & y)), int(np.sum(~x & ~y))
    p1, p2 = (both + only_a) / n, (both + only_b) / n
    l1, u1 = wilson_interval(both + only_a, n)
    l2, u2 = wilson_interval(both + only_b, n)
    den = (both + only_a) * (only_b + neither) * (both + only_b) * (only_a + neither)
    phi = (both * neither - only_a * only_b) / math.sqrt(den) if den > 0 else 0.0
    d = p1 - p2
    lo = d - math.sqrt(max(0.0, (p1 - l1) ** 2 - 2 * phi * (p1 - l1) * (u2 - p2) + (u2 - p2) ** 2))
    hi = d + math.sqrt(max(0.0, (u1 - p1) ** 2 - 2 * phi * (u1 - p1) * (p2 - l2) + (p2 - l2) ** 2))
    disc = only_a + only_b
    p = binomtest(only_a, disc, 0.5).pvalue if disc else 1.0
    return {
        "diff": d,
        "ci95": [max(-1.0, lo), min(1.0, hi)],
        "only_a": only_a,
        "only_b": only_b,
        "mcnemar_p": float(p),
    }
