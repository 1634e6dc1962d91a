"""Choosing :class:`pose.fallback.ConfidenceFallback`'s threshold from sweep trials.

A sweep of the main estimator and the fallback on the same views records, per view, the main
estimate's validity and confidence and both rotation errors; the gated answer for any
threshold follows from those without refitting anything. :func:`gate_curve` scores every
threshold per (protocol, occlusion) cell, so the threshold can be chosen on one seed's trials
and the composition measured on another's (the config ``fallback_threshold_seed1`` of
``benchmarks/results/pose_ablation.json.gz`` was chosen this way).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from pose.fallback import keeps_main
from scorbot_gym.experiments.aggregate import THRESHOLD_DEG


def _by_cell(trials: Sequence[dict], estimator: str) -> dict[tuple, dict]:
    return {
        (t["protocol"], t["occlusion"], t["object"]): t["views"]
        for t in trials
        if t["estimator"] == estimator
    }


def _ok(errors: Sequence[float | None]) -> np.ndarray:
    return np.array([e is not None and e < THRESHOLD_DEG for e in errors], bool)


def gate_curve(
    trials: Sequence[dict], main: str, fallback: str, thresholds: Sequence[float]
) -> list[dict]:
    """One record per (protocol, occlusion): success@5° of ``main``, of ``fallback`` and of the
    gated composition at each threshold (``gated``: ``{threshold: rate}``), over the views
    both estimators answered (the same views: same protocol, object, seed and occlusion)."""
    a, b = _by_cell(trials, main), _by_cell(trials, fallback)
    missing = sorted(set(a) ^ set(b))
    if missing:
        raise ValueError(
            f"{main!r} and {fallback!r} must be swept on the same cells; unmatched: {missing[:3]}"
        )
    cells: dict[tuple, list] = {}
    for key in sorted(a):
        va, vb = a[key], b[key]
        if len(va["valid"]) != len(vb["valid"]):
            raise ValueError(f"cell {key} has {len(va['valid'])} and {len(vb['valid'])} views")
        cells.setdefault(key[:2], []).append((va, vb))
    out = []
    for (protocol, occlusion), pairs in cells.items():
        ok_main = np.concatenate([_ok(va["rot_err_deg"]) for va, _ in pairs])
        ok_back = np.concatenate([_ok(vb["rot_err_deg"]) for _, vb in pairs])
        valid = np.concatenate([np.asarray(va["valid"], bool) for va, _ in pairs])
        conf = np.concatenate([np.asarray(va["score"], float) for va, _ in pairs])
        gated = {}
        for t in thresholds:
            keep = np.array([keeps_main(v, c, t) for v, c in zip(valid, conf, strict=True)])
            gated[float(t)] = round(float(np.where(keep, ok_main, ok_back).mean()), 4)
        out.append(
            {
                "protocol": protocol,
                "occlusion": occlusion,
                "n": int(ok_main.size),
                "main": round(float(ok_main.mean()), 4),
                "fallback": round(float(ok_back.mean()), 4),
                "gated": gated,
            }
        )
    return out


def best_threshold(curve: Sequence[dict]) -> tuple[float, dict[float, float]]:
    """The threshold with the highest mean gated success over the cells (the lowest on ties),
    and every threshold's mean."""
    if not curve:
        raise ValueError("no cells to choose a threshold from")
    ths = sorted(curve[0]["gated"])
    means = {t: round(float(np.mean([c["gated"][t] for c in curve])), 4) for t in ths}
    best = max(ths, key=lambda t: (means[t], -t))
    return best, means
