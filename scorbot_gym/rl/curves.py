"""Learning curves over seeds: mean success and a 95 % band, against env steps and wall time.

Each run's curve is its own evaluation history (``checkpoint/state.json``: success rate and
mean return on held-out seeds, with the env steps and the training wall time at which they
were measured). The
seeds of an arm are put on a common axis by linear interpolation, over the range every seed
reached (no extrapolation), and the band is the Student-t 95 % interval of the mean over seeds
(none for a single seed): what RL papers print, e.g. rliable's and RL Zoo's plots.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from scorbot_gym.rl import runs

#: the settings of an arm's first run that the report repeats (what the curve is of)
SETTINGS_SHOWN = (
    "algo",
    "pose",
    "action_type",
    "objects",
    "residual",
    "bc_demos",
    "n_envs",
    "timesteps",
    "eval_every",
    "eval_episodes",
    "hyperparams",
)


def expand_runs(paths: Sequence[str | Path]) -> list[Path]:
    """Run folders, a ``--seeds`` folder standing for its per-seed runs."""
    out: list[Path] = []
    for p in map(Path, paths):
        seeds = runs.seed_runs(p) if not (p / runs.CONFIG).is_file() else []
        out.extend(seeds or [p])
    return out


def eval_history(run: str | Path) -> dict[str, Any]:
    """A run's evaluations as arrays (``timesteps``, ``wall_s``, ``success_rate``) + its seed."""
    run = Path(run)
    state = runs.read_json(run / runs.CHECKPOINT / runs.STATE, "the training state")
    evals = state.get("eval")
    if not isinstance(evals, list) or not evals:
        raise ValueError(f"{run}: no evaluations recorded yet")
    config = state.get("config") or runs.read_json(run / runs.CONFIG)
    return {
        "run": str(run),
        "seed": config.get("seed"),
        "config": config,
        "timesteps": np.array([e["timesteps"] for e in evals], float),
        "wall_s": np.array([e["wall_s"] for e in evals], float),
        "success_rate": np.array([e["success_rate"] for e in evals], float),
        # NaN for evaluations from before the return was recorded
        "mean_return": np.array([e.get("mean_return", np.nan) for e in evals], float),
        # where the last evaluation's failed episodes ended and came closest to the grasp
        # point (median, m; None before runs recorded it, or when none failed)
        "failed_grasp_distance_m": {
            k: evals[-1].get(f"failed_median_{k}_grasp_distance_m") for k in ("final", "closest")
        },
    }


def _band(values: np.ndarray, clip: bool = True) -> dict[str, list[float] | None]:
    """Mean over seeds (rows) per point and the t-interval of the mean (a rate's clipped to
    [0, 1])."""
    from scipy import stats

    mean = values.mean(axis=0)
    n = values.shape[0]
    if n < 2:
        return {"mean": mean.tolist(), "ci95_low": None, "ci95_high": None}
    half = stats.t.ppf(0.975, n - 1) * values.std(axis=0, ddof=1) / np.sqrt(n)
    low, high = mean - half, mean + half
    if clip:
        low, high = np.clip(low, 0.0, 1.0), np.clip(high, 0.0, 1.0)
    return {"mean": mean.tolist(), "ci95_low": low.tolist(), "ci95_high": high.tolist()}


def curve(
    histories: Sequence[dict[str, Any]],
    axis: str,
    points: int = 50,
    metric: str = "success_rate",
) -> dict[str, Any]:
    """Mean and band of the seeds' ``metric`` (``success_rate`` or ``mean_return``) against
    ``axis`` (``timesteps`` or ``wall_s``).

    Env steps use the union of the evaluation points (they coincide when every seed evaluates
    on the same schedule); wall time, which differs between seeds, ``points`` even steps."""
    end = min(h[axis][-1] for h in histories)
    if axis == "timesteps":
        grid = np.unique(np.concatenate([h[axis][h[axis] <= end] for h in histories]))
    else:
        start = max(h[axis][0] for h in histories)
        grid = np.linspace(start, end, points) if end > start else np.array([end])
    values = np.stack([np.interp(grid, h[axis], h[metric]) for h in histories])
    return {axis: grid.tolist(), **_band(values, clip=metric == "success_rate")}


def first_reached(histories: Sequence[dict[str, Any]], level: float) -> dict[str, Any]:
    """Per seed, the env steps and training wall time of the first evaluation whose success
    rate is at least ``level`` (None: not reached), and how many seeds reached it."""
    steps, walls = [], []
    for h in histories:
        hit = np.flatnonzero(h["success_rate"] >= level)
        steps.append(int(h["timesteps"][hit[0]]) if hit.size else None)
        walls.append(float(h["wall_s"][hit[0]]) if hit.size else None)
    return {
        "timesteps": steps,
        "wall_s": walls,
        "seeds_reached": sum(s is not None for s in steps),
    }


def peak(history: dict[str, Any]) -> dict[str, Any]:
    """A seed's best evaluation (the first among equals): success rate and env steps. Not
    monotone curves make the last evaluation a poor summary of what a run reached."""
    i = int(np.argmax(history["success_rate"]))
    return {
        "success_rate": float(history["success_rate"][i]),
        "timesteps": int(history["timesteps"][i]),
    }


def learning_curves(arms: Mapping[str, Sequence[str | Path]], points: int = 50) -> dict[str, Any]:
    """Per arm (label -> run folders, a ``--seeds`` folder counting as its seeds): the seeds and
    the mean success with its 95 % band against env steps and against training wall time."""
    report: dict[str, Any] = {}
    for label, paths in arms.items():
        histories = [eval_history(r) for r in expand_runs(paths)]
        if not histories:
            raise ValueError(f"arm {label!r}: no run folders")
        report[label] = {
            "settings": {k: histories[0]["config"].get(k) for k in SETTINGS_SHOWN},
            "runs": [h["run"] for h in histories],
            "seeds": [h["seed"] for h in histories],
            "final_success_rate": [float(h["success_rate"][-1]) for h in histories],
            "final_failed_grasp_distance_m": [h["failed_grasp_distance_m"] for h in histories],
            "by_timesteps": curve(histories, "timesteps", points),
            "by_wall_s": curve(histories, "wall_s", points),
            "first_reached": {f"{lv:g}": first_reached(histories, lv) for lv in (0.5, 0.8)},
            "peak": [peak(h) for h in histories],
            # each seed's own evaluations: the mean stops where the shortest run does
            "per_seed": [
                {
                    "seed": h["seed"],
                    "timesteps": h["timesteps"].astype(int).tolist(),
                    "success_rate": h["success_rate"].tolist(),
                }
                for h in histories
            ],
        }
        if all(np.isfinite(h["mean_return"]).all() for h in histories):
            report[label]["return_by_timesteps"] = curve(
                histories, "timesteps", points, "mean_return"
            )
            report[label]["return_by_wall_s"] = curve(histories, "wall_s", points, "mean_return")
    return report


def reward_type(arm: Mapping[str, Any]) -> str:
    """The reward an arm's runs were trained and evaluated on (``dense`` before runs
    recorded it: the env's default then), with the discount a normalised one is built for
    where it is not 0.99 (its returns are on another scale)."""
    hp = (arm.get("settings") or {}).get("hyperparams") or {}
    name, built_for = str(hp.get("reward_type", "dense")), hp.get("reward_gamma", 0.99)
    return name if built_for == 0.99 else f"{name}, reward_gamma {built_for}"


def plot_learning_curves(report: Mapping[str, Any], path: str | Path) -> None:
    """Success against env steps and against training wall time, one line + band per arm; a
    second row for the mean return where every arm recorded it."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pose.fileio import atomic_write_bytes

    rows = [("", "success rate (held-out seeds)")]
    rewards = {reward_type(arm) for arm in report.values()}
    # returns of different rewards are not on one scale: drawn only when the arms share one
    if report and len(rewards) == 1 and all("return_by_timesteps" in a for a in report.values()):
        rows.append(("return_", f"mean return, {rewards.pop()} (held-out seeds)"))
    fig, axes = plt.subplots(
        len(rows), 2, figsize=(10, 3.8 * len(rows)), sharey="row", squeeze=False
    )
    for r, (prefix, ylabel) in enumerate(rows):
        for label, arm in report.items():
            n = len(arm["seeds"])
            for ax, key, axis in (
                (axes[r, 0], f"{prefix}by_timesteps", "timesteps"),
                (axes[r, 1], f"{prefix}by_wall_s", "wall_s"),
            ):
                c = arm[key]
                x = np.asarray(c[axis]) / (60.0 if axis == "wall_s" else 1.0)
                (line,) = ax.plot(x, c["mean"], label=f"{label} ({n} seed{'s' * (n > 1)})")
                if c["ci95_low"] is not None:
                    ax.fill_between(
                        x, c["ci95_low"], c["ci95_high"], alpha=0.25, color=line.get_color()
                    )
                if not prefix and axis == "timesteps" and n > 1:  # each seed, thin
                    for run in arm.get("per_seed", []):
                        ax.plot(run["timesteps"], run["success_rate"], lw=0.6, alpha=0.5,
                                color=line.get_color())  # fmt: skip
        axes[r, 0].set_xlabel("env steps")
        axes[r, 1].set_xlabel("training wall time (min)")
        axes[r, 0].set_ylabel(ylabel)
    axes[0, 0].set_ylim(-0.02, 1.02)
    axes[0, 0].legend(loc="upper left", fontsize=7, framealpha=0.9)
    fig.suptitle(
        "mean over seeds (to the shortest run), band: 95 % CI of the mean; thin: each seed"
    )
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())


__all__ = [
    "curve",
    "eval_history",
    "expand_runs",
    "first_reached",
    "learning_curves",
    "plot_learning_curves",
]
