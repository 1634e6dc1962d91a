"""The ablation study end to end: run a sweep, aggregate it, and report it (JSON + PNG).

The ``pose ablate`` CLI and ``benchmarks/pose_ablation.py`` both call :func:`ablate`.
"""

from __future__ import annotations

import os

from pose.fileio import atomic_write_json
from scorbot_gym.experiments.aggregate import (
    aggregate,
    chance_level,
    curve_summary,
    fit_errors,
    selections,
    stage_ablation,
    view_errors,
    winners,
)
from scorbot_gym.experiments.plot import plot_success_vs_occlusion
from scorbot_gym.experiments.runners import Runner, run_sweep
from scorbot_gym.experiments.spec import SweepSpec


def ablate(spec: SweepSpec, runner: Runner | None = None, cache_dir: str | None = None) -> dict:
    """Run (or resume) the sweep; returns the report. ``report["trials"]`` holds the per-view
    records (estimates and ground truth, e.g. for :mod:`scorbot_gym.evaluation.bop`); the JSON
    written by :func:`write_report` leaves them out (they stay in the trial cache)."""
    sweep = run_sweep(spec, runner, cache_dir)
    results = aggregate(sweep["trials"])
    chance = chance_level(results)
    return {
        "spec": sweep["spec"],
        "results": results,
        "chance": chance,
        "stage_ablation": stage_ablation(results),
        "curves": curve_summary(results, chance),
        "winners": winners(results),
        "stats": sweep["stats"],
        "fit_errors": fit_errors(sweep["trials"]),
        "selections": selections(sweep["trials"]),
        "view_errors": view_errors(sweep["trials"]),
        "trials": sweep["trials"],
    }


def write_report(
    report: dict,
    json_path: str | os.PathLike | None = None,
    png_path: str | os.PathLike | None = None,
) -> None:
    if json_path:
        atomic_write_json(json_path, {k: v for k, v in report.items() if k != "trials"})
    if png_path:
        s = report["spec"]
        title = (
            f"{s['protocol']} (v{s['protocol_info']['version']}), {len(s['objects'])} objects, "
            f"{s['width']}x{s['height']}, seed {s['seed']}"
        )
        if s["protocol_info"].get("occlusion") == "measured, binned":
            title += "; occlusion measured from the segmentation, 10 % bins (lower edge)"
        plot_success_vs_occlusion(report["results"], report["chance"], png_path, title)
