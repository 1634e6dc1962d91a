"""The figure of a scripted-vs-learned comparison (:mod:`scorbot_gym.evaluation.compare`), as a
paper would print it.

The claim of a comparison is the *paired* difference of each policy from the reference (the
scripted controller) under each pose condition, and those differences are a few points, so:

- **success** per arm as a point with its Wilson 95 % interval on an axis zoomed to the
  data (a 0-1 bar chart hides a 2-point difference);
- **paired difference** from the reference as a forest plot: Δ in points with Newcombe's
  95 % interval, a line at 0, the point filled where the interval excludes 0; beside it the
  numbers (success with its interval, Δ with its interval, McNemar's exact p);
- **per object**: successes / episodes of every arm, as a table coloured by the rate
  (per-object counts are small: the counts say how small);
- **pose noise**: one axis per kind of noise (position only, heading only, both scaled
  together), each starting at the true pose, so that two kinds of noise are never joined by
  one line as if they were one axis.

:func:`plot_comparison` reads only the report (also older ones: a missing ``label`` is the
policy's name, a missing ``noise_yaw_deg`` the heading that went with the position noise,
missing differences are recomputed from ``episode_success``), so a figure is redrawn from the
JSON without running an episode.
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from scorbot_gym.evaluation.summary import newcombe_paired_diff

NOISE_KINDS = ("position", "heading", "both")


def _label(r: dict[str, Any]) -> str:
    from scorbot_gym.evaluation.compare import policy_label

    return str(r.get("label") or policy_label(r["policy"]))


def _noise(r: dict[str, Any], deg_per_m: float) -> tuple[float, float] | None:
    """(position m, heading deg) of an oracle or noisy arm; ``None`` for the estimator ones.
    Older reports record no heading: ``noisy@S`` then meant S metres with ``S * deg_per_m``
    degrees."""
    pos = r.get("noise_pos_m")
    if pos is None:
        return None
    yaw = r.get("noise_yaw_deg")
    return float(pos), float(pos * deg_per_m if yaw is None else yaw)


def noise_kind(pos_m: float, yaw_deg: float) -> str | None:
    """``position``, ``heading``, ``both`` or ``None`` (no noise: the true pose)."""
    if pos_m > 0 and yaw_deg > 0:
        return "both"
    if pos_m > 0:
        return "position"
    return "heading" if yaw_deg > 0 else None


def condition_title(pose: str, noise: tuple[float, float] | None, short: bool = False) -> str:
    """A pose condition in words (``noisy@0.02:0`` -> ``position noise σ 2 cm``, ``short``:
    ``position 2 cm``)."""
    if pose == "manifold":
        return "estimated pose" if short else "pose from the images"
    if pose == "chance":
        return "image-blind pose" if short else "image-blind (chance)"
    if pose.startswith("occluded"):
        where = f" ({pose.partition('@')[2].replace(':', '–')} m)" if "@" in pose else ""
        return (
            f"hidden near the hand{where}" if short else f"true pose, hidden near the hand{where}"
        )
    if noise is None:
        return pose
    pos, yaw = noise
    kind = noise_kind(pos, yaw)
    if kind is None:
        return "true pose" if pose == "oracle" else pose
    parts = {
        "position": f"position noise σ {100 * pos:g} cm",
        "heading": f"heading noise σ {yaw:g}°",
        "both": f"noise σ {100 * pos:g} cm + {yaw:g}°",
    }
    return parts[kind].replace(" noise σ", "") if short else parts[kind]


def _differences(report: dict[str, Any], ref: str) -> dict[tuple[str, str], dict[str, Any]]:
    """``(policy, pose) -> {diff, ci95, mcnemar_p}`` against ``ref``: the report's own, or
    recomputed from the per-episode outcomes where the report has none."""
    out = {(d["a"], d["pose"]): d for d in report.get("differences") or () if d["b"] == ref}
    by = {(r["policy"], r["pose"]): r for r in report["results"]}
    for (policy, pose), r in by.items():
        base = by.get((ref, pose))
        if policy == ref or (policy, pose) in out or base is None:
            continue
        if r.get("episode_success") and base.get("episode_success"):
            a = [c == "1" for c in r["episode_success"]]
            b = [c == "1" for c in base["episode_success"]]
            out[(policy, pose)] = newcombe_paired_diff(a, b)
    return out


def _rows(poses: list[str], policies: list[str], by: dict) -> list[tuple[str, str | None]]:
    """The forest plot's rows, top to bottom: each condition's header, then its arms."""
    rows: list[tuple[str, str | None]] = []
    for pose in poses:
        rows.append((pose, None))
        rows += [(pose, p) for p in policies if (p, pose) in by]
    return rows


def _pct(v: float) -> float:
    return 100.0 * v


def _draw_success_and_differences(fig, spec, report, ref, colors, diffs) -> list[str]:
    res = report["results"]
    deg_per_m = float(report.get("noise_heading_deg_per_m", 500.0))
    policies = list(dict.fromkeys(r["policy"] for r in res))
    poses = list(dict.fromkeys(r["pose"] for r in res))
    by = {(r["policy"], r["pose"]): r for r in res}
    rows = _rows(poses, policies, by)
    has_diff = bool(diffs)
    ratios = [1.0, 1.1, 1.2] if has_diff else [1.0, 0.6]
    sub = spec.subgridspec(1, len(ratios), width_ratios=ratios, wspace=0.1)
    ax_s = fig.add_subplot(sub[0])
    ax_d = fig.add_subplot(sub[1], sharey=ax_s) if has_diff else None
    ax_t = fig.add_subplot(sub[-1], sharey=ax_s)
    ys = np.arange(len(rows))
    lows = []
    for y, (pose, policy) in zip(ys, rows, strict=True):
        if policy is None:
            for ax in filter(None, (ax_s, ax_d)):
                ax.axhspan(y - 0.5, y + 0.5, color="0.92", lw=0)
            continue
        r = by[(policy, pose)]
        p, (lo, hi) = r["success_rate"], r["ci95"]
        lows.append(lo)
        ax_s.errorbar(
            _pct(p), y, xerr=[[_pct(p - lo)], [_pct(hi - p)]], fmt="o", ms=5, capsize=2.5,
            color=colors[policy],
        )  # fmt: skip
        text = f"{_pct(p):.1f} ({_pct(lo):.1f}–{_pct(hi):.1f})"
        d = diffs.get((policy, pose))
        if ax_d is not None and d is not None:
            dlo, dhi = d["ci95"]
            excludes_zero = dlo > 0 or dhi < 0
            ax_d.errorbar(
                _pct(d["diff"]), y, xerr=[[_pct(d["diff"] - dlo)], [_pct(dhi - d["diff"])]],
                fmt="o", ms=5, capsize=2.5, color=colors[policy],
                mfc=colors[policy] if excludes_zero else "white",
            )  # fmt: skip
            ax_t.text(0.0, y, text, va="center", fontsize=8)
            ax_t.text(
                0.38, y,
                f"{_pct(d['diff']):+.1f} ({_pct(dlo):+.1f} to {_pct(dhi):+.1f})",
                va="center", fontsize=8,
            )  # fmt: skip
            ax_t.text(0.8, y, f"{d['mcnemar_p']:.2g}", va="center", fontsize=8)
        else:
            ax_t.text(0.0, y, text, va="center", fontsize=8)
            if policy == ref and has_diff:
                ax_t.text(0.38, y, "reference", va="center", fontsize=8, color="0.4")
    names = {(pose, p): _label(by[(p, pose)]) for pose, p in rows if p is not None}
    ticks = [
        condition_title(pose, _noise(by[(policies[0], pose)], deg_per_m))
        if (policies[0], pose) in by and policy is None
        else (pose if policy is None else names[(pose, policy)])
        for pose, policy in rows
    ]
    ax_s.set_yticks(ys, ticks, fontsize=8.5)
    # room on the left for the longest label (bold, about 0.075 inch a character at 8.5 pt)
    longest = max([len(t) for t in ticks] + [16])  # 16: the object names below
    fig.subplots_adjust(left=min(0.35, (0.25 + 0.075 * longest) / fig.get_figwidth()))
    for tick, (_, policy) in zip(ax_s.get_yticklabels(), rows, strict=True):
        if policy is None:
            tick.set_fontweight("bold")
    ax_s.set_ylim(len(rows) - 0.5, -1.3)
    left = max(0.0, np.floor(_pct(min(lows)) / 5.0) * 5.0 - 2.5)
    ax_s.set_xlim(left, 101.0)
    ax_s.set_xlabel("success, % (95 % Wilson)", fontsize=9)
    ax_s.grid(axis="x", color="0.85", lw=0.6)
    ax_s.set_axisbelow(True)
    ax_t.axis("off")
    ax_t.set_xlim(0, 1)
    head_y = -0.9
    ax_t.text(0.0, head_y, "success, %", fontsize=8, fontweight="bold")
    drawn = ["success"]
    if ax_d is not None:
        ax_t.text(0.38, head_y, f"Δ vs {ref}, points", fontsize=8, fontweight="bold")
        ax_t.text(0.8, head_y, "p", fontsize=8, fontweight="bold")
        ax_d.axvline(0.0, color="0.3", lw=0.8, ls="--")
        span = max(
            [abs(_pct(v)) for d in diffs.values() for v in d["ci95"]] + [1.0]
        )  # symmetric about 0: the sign is what matters
        ax_d.set_xlim(-1.1 * span, 1.1 * span)
        ax_d.set_xlabel(f"paired Δ vs {ref}, points (95 % Newcombe)", fontsize=9)
        ax_t.text(0.0, len(rows) - 0.5, "p: McNemar's exact test", va="top", fontsize=7.5,
                  color="0.35")  # fmt: skip
        ax_d.tick_params(axis="y", left=False, labelleft=False)
        ax_d.grid(axis="x", color="0.85", lw=0.6)
        ax_d.set_axisbelow(True)
        drawn.append("differences")
    return drawn


def _draw_objects(ax, report, colors) -> None:
    from matplotlib.transforms import blended_transform_factory

    res = report["results"]
    deg_per_m = float(report.get("noise_heading_deg_per_m", 500.0))
    objects = sorted({o for r in res for o in r.get("per_object", {})})
    rates = np.full((len(objects), len(res)), np.nan)
    counts = {}
    for j, r in enumerate(res):
        for i, o in enumerate(objects):
            v = r["per_object"].get(o)
            if v and v.get("episodes"):
                rates[i, j] = v["successes"] / v["episodes"]
                counts[(i, j)] = f"{v['successes']}/{v['episodes']}"
    low = min(float(np.nanmin(rates)) if counts else 0.0, 0.5)
    image = ax.imshow(np.ma.masked_invalid(rates), cmap="RdYlGn", vmin=low, vmax=1.0, aspect="auto")
    for (i, j), text in counts.items():  # white on the dark red end of the scale
        dark = (rates[i, j] - low) / (1.0 - low) < 0.2
        ax.text(j, i, text, ha="center", va="center", fontsize=6,
                color="white" if dark else "black")  # fmt: skip
    ax.set_yticks(range(len(objects)), objects, fontsize=8)
    ax.set_xticks(range(len(res)), [_label(r) for r in res], fontsize=7.5, rotation=45,
                  ha="right", rotation_mode="anchor")  # fmt: skip
    for tick, r in zip(ax.get_xticklabels(), res, strict=True):
        tick.set_color(colors[r["policy"]])
    # the conditions over their columns
    poses = list(dict.fromkeys(r["pose"] for r in res))
    above = blended_transform_factory(ax.transData, ax.transAxes)
    for pose in poses:
        cols = [j for j, r in enumerate(res) if r["pose"] == pose]
        title = condition_title(pose, _noise(res[cols[0]], deg_per_m), short=True)
        ax.text((cols[0] + cols[-1]) / 2, 1.01, title, ha="center", va="bottom", fontsize=7.5,
                transform=above)  # fmt: skip
        if cols[0] > 0:
            ax.axvline(cols[0] - 0.5, color="white", lw=2.5)
    ax.set_title("per object: successes / episodes", fontsize=9, pad=16)
    bar = ax.figure.colorbar(image, ax=ax, fraction=0.035, pad=0.015)
    bar.ax.tick_params(labelsize=7)


def _noise_points(report) -> dict[str, dict[str, list[dict[str, Any]]]]:
    """``kind -> policy -> points`` by increasing noise, each kind starting at the true pose."""
    deg_per_m = float(report.get("noise_heading_deg_per_m", 500.0))
    out: dict[str, dict[str, list[dict[str, Any]]]] = {}
    arms = [(r, _noise(r, deg_per_m)) for r in report["results"]]
    kinds = {noise_kind(*n) for _, n in arms if n is not None} - {None}
    for kind in NOISE_KINDS:
        if kind not in kinds:
            continue
        for r, n in arms:
            if n is not None and noise_kind(*n) in (kind, None):
                x = 100 * n[0] if kind != "heading" else n[1]
                point = {"x": x, "rate": r["success_rate"], "ci95": r["ci95"], "noise": n}
                out.setdefault(kind, {}).setdefault(r["policy"], []).append(point)
        for points in out[kind].values():
            points.sort(key=lambda p: p["x"])
    return out


def _draw_noise(axes: Sequence, curves, report, colors) -> list[str]:
    by = {r["policy"]: r for r in report["results"]}
    lows = []
    for ax, (kind, per_policy) in zip(axes, curves.items(), strict=True):
        xmax = max(p["x"] for pts in per_policy.values() for p in pts) or 1.0
        shift = 0.02 * xmax  # side by side: overlapping intervals stay visible
        for i, (policy, pts) in enumerate(per_policy.items()):
            xs = np.array([p["x"] for p in pts]) + (i - (len(per_policy) - 1) / 2) * shift
            ys = np.array([_pct(p["rate"]) for p in pts])
            lo = ys - np.array([_pct(p["ci95"][0]) for p in pts])
            hi = np.array([_pct(p["ci95"][1]) for p in pts]) - ys
            lows += list(ys - lo)
            ax.errorbar(
                xs, ys, yerr=[lo, hi], marker="o", ms=4, capsize=2.5, lw=1.2,
                color=colors[policy], label=_label(by[policy]),
            )  # fmt: skip
        if kind == "heading":
            ax.set_xlabel("heading noise σ, degrees", fontsize=9)
        elif kind == "position":
            ax.set_xlabel("position noise σ, cm", fontsize=9)
        else:
            pts = next(iter(per_policy.values()))
            ratio = [p["noise"][1] / (100 * p["noise"][0]) for p in pts if p["noise"][0] > 0]
            ax.set_xlabel(
                f"position noise σ, cm (with {np.median(ratio):g}° heading per cm)", fontsize=9
            )
        ax.set_title(f"{kind} noise" if kind != "both" else "position + heading noise", fontsize=9)
        ax.grid(color="0.88", lw=0.6)
        ax.tick_params(labelsize=8)
    bottom = max(0.0, np.floor(min(lows) / 5.0) * 5.0 - 2.5)
    axes[0].set_ylim(bottom, 101.0)
    axes[0].set_ylabel("success, % (95 % Wilson)", fontsize=9)
    axes[0].legend(fontsize=7.5, loc="best", frameon=True, framealpha=0.85)
    return [f"noise_{kind}" for kind in curves]


def _caption(res: list[dict[str, Any]], trained_from: dict[str, str]) -> str:
    """What each policy was trained from, policies with the same answer together, wrapped."""
    import textwrap

    groups: dict[str, list[str]] = {}
    for r in res:
        t = (r.get("training") or {}).get("trained_from")
        if t and _label(r) not in groups.get(trained_from.get(t, t), []):
            groups.setdefault(trained_from.get(t, t), []).append(_label(r))
    text = "; ".join(f"{', '.join(names)}: {what}" for what, names in groups.items())
    return "\n".join(textwrap.wrap(text, 170))


def plot_comparison(report: dict[str, Any], path: str | Path) -> list[str]:
    """Draw the comparison figure of ``report`` (:func:`~scorbot_gym.evaluation.compare.compare`'s
    result, or its JSON) to the PNG ``path``; returns the panels drawn, in order, from
    ``success``, ``differences`` (only with a reference to differ from), ``objects`` (only with
    per-object records) and ``noise_position`` / ``noise_heading`` / ``noise_both`` (one axis
    per kind of pose noise the report has)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pose.fileio import atomic_write_bytes
    from scorbot_gym.evaluation.compare import TRAINED_FROM

    res = report["results"]
    if not res:
        raise ValueError("the comparison report has no results to plot")
    policies = list(dict.fromkeys(r["policy"] for r in res))
    ref = report.get("reference") or policies[0]
    colors = {p: plt.cm.tab10(i % 10) for i, p in enumerate(policies)}
    diffs = _differences(report, ref)
    curves = _noise_points(report)
    has_objects = any(r.get("per_object") for r in res)
    n_rows = len(_rows(list(dict.fromkeys(r["pose"] for r in res)), policies,
                       {(r["policy"], r["pose"]): r for r in res}))  # fmt: skip
    n_objects = len({o for r in res for o in r.get("per_object", {})})
    caption = _caption(res, TRAINED_FROM)
    # every height in inches: the title, the forest rows, room for the x labels and the next
    # panel's titles, the per-object rows, the rotated column labels and the caption
    width = 12.0
    top_margin, top_h = 0.45, 0.3 + 0.24 * (n_rows + 1)
    bottom = has_objects or bool(curves)
    gap = 1.2 if bottom else 0.0
    bottom_h = (0.3 + 0.26 * max(n_objects, 6)) if bottom else 0.0
    longest = max(len(_label(r)) for r in res) if has_objects else 0
    bottom_margin = 0.55 + 0.05 * longest + 0.16 * caption.count("\n") + (0.2 if caption else 0)
    height = top_margin + top_h + gap + bottom_h + bottom_margin
    fig = plt.figure(figsize=(width, height))
    heights = [top_h, gap, bottom_h] if bottom else [top_h]
    grid = fig.add_gridspec(len(heights), 1, height_ratios=heights, hspace=0.0)
    panels = _draw_success_and_differences(fig, grid[0], report, ref, colors, diffs)
    if bottom:
        # the table's columns about half an inch wide, each noise axis 2.6 inches, the rest
        # left empty (a wide table of a few columns says no more)
        widths = ([1.0 + 0.5 * len(res)] if has_objects else []) + [2.6] * len(curves)
        spare = 0.8 * width - sum(widths) - 0.9 * (len(widths) - 1)
        sub = grid[2].subgridspec(
            1, len(widths) + (spare > 0), width_ratios=widths + ([spare] if spare > 0 else []),
            wspace=0.35,
        )  # fmt: skip
        k = 0
        if has_objects:
            _draw_objects(fig.add_subplot(sub[0]), report, colors)
            panels.append("objects")
            k = 1
        if curves:
            first = fig.add_subplot(sub[k])
            rest = [fig.add_subplot(sub[k + i], sharey=first) for i in range(1, len(curves))]
            axes = [first, *rest]
            panels += _draw_noise(axes, curves, report, colors)
    seeds = report.get("seeds") or [None, None]
    objects = report.get("objects")
    scope = "whole catalogue" if not objects else ", ".join(objects)
    actions = f", {report['action_type']} actions" if report.get("action_type") else ""
    fig.suptitle(
        f"{report['episodes']} paired episodes per arm (seeds {seeds[0]}–{seeds[-1]}), "
        f"{scope}{actions}",
        fontsize=10, y=1 - 0.12 / height,
    )  # fmt: skip
    if caption:
        fig.text(0.5, 0.08 / height, caption, ha="center", va="bottom", fontsize=7.5,
                 color="0.3")  # fmt: skip
    fig.subplots_adjust(right=0.985, top=1 - top_margin / height, bottom=bottom_margin / height)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=120)
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())
    return panels
