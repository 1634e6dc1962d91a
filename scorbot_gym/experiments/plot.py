"""The seed's Fig. 3: success@5° against occlusion, one curve per estimator with its 95 %
Wilson band, the chance level, and (dotted) an estimator's answer before refinement where it
reports one that differs."""

from __future__ import annotations

import io
import os
import textwrap
from collections.abc import Sequence

from pose.fileio import atomic_write_bytes


def legend_label(spec: str, width: int = 64) -> str:
    """A full estimator spec over several lines: two compositions that differ only in their
    last parameters must stay distinguishable in the legend, so specs are wrapped, never cut."""
    return "\n".join(textwrap.wrap(spec, width, break_on_hyphens=False)) or spec


#: above this many curves the figure highlights a few and draws the rest thin
MANY_CURVES = 6


def highlighted(results: Sequence[dict]) -> tuple[str | None, str | None]:
    """The two curves a reader compares first: the best estimator built on the pose manifold
    and the best baseline other than ``chance`` (``None`` where the sweep has none), each by
    its success@5° over all its views (every level weighted by its ``n``: a bin of measured
    occlusion with two views does not outweigh one with eight hundred)."""
    from scorbot_gym.experiments.aggregate import CHANCE_ESTIMATOR, builds_on_manifold

    hits: dict[str, list[float]] = {}
    for r in results:
        if r["n"]:
            k = hits.setdefault(r["estimator"], [0.0, 0.0])
            k[0] += (r["success_5deg"] or 0.0) * r["n"]
            k[1] += r["n"]
    score = {label: k / n for label, (k, n) in hits.items()}

    def best(labels: list[str]) -> str | None:
        return max(labels, key=lambda label: score[label]) if labels else None

    ours = [label for label in score if builds_on_manifold(label)]
    theirs = [label for label in score if label not in ours and label != CHANCE_ESTIMATOR]
    return best(ours), best(theirs)


def plot_success_vs_occlusion(
    results: Sequence[dict], chance: dict, path: str | os.PathLike, title: str = ""
) -> None:
    """Write :func:`success_figure` to ``path`` (PNG, atomically)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = success_figure(results, chance, title)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", bbox_inches="tight")  # the legend beside the axes included
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())


def success_figure(results: Sequence[dict], chance: dict, title: str = ""):
    """success@5° against occlusion, one curve per estimator (a matplotlib ``Figure``).

    Up to :data:`MANY_CURVES` estimators, every curve is drawn alike with its 95 % Wilson band
    (and, dotted, the answer before refinement where it differs). With more, eleven curves
    drawn alike cannot be read: the best estimator built on the pose manifold and the best
    baseline (:func:`highlighted`) are drawn thick with their bands, every other curve thin
    and without band (still in the legend, in its own colour), and a star marks each level
    where a baseline beats everything built on the manifold (the report's ``winners``). The
    chance level is dashed. Where the levels hold different numbers of views (binned measured
    occlusion), each level's ``n`` is written under it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from scorbot_gym.experiments.aggregate import winners

    labels = list(dict.fromkeys(r["estimator"] for r in results))
    many = len(labels) > 4  # legend beside the axes, colours from a 20-colour cycle
    crowded = len(labels) > MANY_CURVES
    best_ours, best_theirs = highlighted(results) if crowded else (None, None)
    tag = {best_ours: " [best built on the manifold]", best_theirs: " [best baseline]"}
    lead = [h for h in (best_ours, best_theirs) if h is not None] if crowded else labels
    fig, ax = plt.subplots(figsize=(12 if crowded else 10.5 if many else 7, 4.8), dpi=120)
    colours = plt.get_cmap("tab20" if many else "tab10").colors
    if many:  # tab20 pairs a dark and a light shade of each hue: all ten hues first
        colours = colours[0::2] + colours[1::2]
    if crowded:  # the highlighted two in the strongest colours, every other curve after them
        labels = lead + [label for label in labels if label not in lead]
    for k, label in enumerate(labels):
        rows = sorted(
            (r for r in results if r["estimator"] == label and r["n"]),  # empty bins: no point
            key=lambda r: r["occlusion"],
        )
        x = [100 * r["occlusion"] for r in rows]
        y = [100 * (r["success_5deg"] or 0.0) for r in rows]
        lo = [100 * r["success_5deg_ci95"][0] for r in rows]
        hi = [100 * r["success_5deg_ci95"][1] for r in rows]
        colour = colours[k % len(colours)]
        strong = label in lead
        text = legend_label(label) + tag.get(label, "")
        (line,) = ax.plot(
            x, y, marker="o", ms=3.5 if strong else 2, lw=2.2 if crowded and strong else
            1.5 if strong else 0.9, alpha=1.0 if strong else 0.6, label=text, color=colour,
            zorder=3 if strong else 2,
        )  # fmt: skip
        if strong:
            ax.fill_between(x, lo, hi, color=line.get_color(), alpha=0.06 if many else 0.15,
                            lw=0)  # fmt: skip
        coarse = [
            (xi, r["coarse_success_5deg"], r["success_5deg"])
            for xi, r in zip(x, rows, strict=True)
            if r.get("coarse_success_5deg") is not None
        ]
        if strong and any(c != s for _, c, s in coarse):
            ax.plot(
                [c[0] for c in coarse], [100 * c[1] for c in coarse], ls=":",
                color=line.get_color(), label=legend_label(f"{label} [coarse: before refinement]"),
            )  # fmt: skip
    pts = [c for c in chance["success_5deg"] if c["value"] is not None]
    if pts:
        ax.plot(
            [100 * c["occlusion"] for c in pts], [100 * c["value"] for c in pts],
            "k--", lw=1, label="chance (image-blind)",
        )  # fmt: skip
    if crowded:
        won = [w for w in winners(results) if w["baseline_wins"]]
        if won:
            ax.plot(
                [100 * w["occlusion"] for w in won], [100 * w["best_success_5deg"] for w in won],
                "k*", ms=9, mfc="none", zorder=4,
                label="a baseline (or the image-blind answer) beats every manifold estimator",
            )  # fmt: skip
    counts = {r["occlusion"]: r["n"] for r in results}
    binned = len(set(counts.values())) > 1
    if binned:  # binned levels: say how many views each one holds (an empty one too)
        levels = sorted(counts)
        ax.set_xticks([100 * o for o in levels])
        ax.set_xlim(100 * levels[0] - 3, 100 * levels[-1] + 3)
        for occ in levels:
            ax.annotate(f"n={counts[occ]}", (100 * occ, 0), xycoords=ax.get_xaxis_transform(),
                        xytext=(0, -22), textcoords="offset points", ha="center", va="top",
                        fontsize=6, color="0.35", annotation_clip=False)  # fmt: skip
    ax.set_xlabel("occlusion (% of the object's mask hidden)", labelpad=14 if binned else 4)
    ax.set_ylabel("success @ 5° (%)")
    ax.set_ylim(-2, 102)
    ax.grid(alpha=0.3)
    ax.set_title(title, fontsize=9)
    if many:
        ax.legend(fontsize=6, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    else:
        ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    return fig


def plot_success_vs_parameter(
    curves: dict[str, Sequence[dict]],
    param: str,
    path: str | os.PathLike,
    title: str = "",
    default: float | None = None,
) -> None:
    """success@5° against a parameter's value, one curve (with its 95 % Wilson band) per
    entry of ``curves``: ``{label: [{"value", "success_5deg", "success_5deg_ci95"}, ...]}``;
    ``default`` marks the parameter's default value."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5), dpi=120)
    for label, rows in curves.items():
        rows = sorted(rows, key=lambda r: r["value"])
        x = [r["value"] for r in rows]
        (line,) = ax.plot(x, [100 * r["success_5deg"] for r in rows], marker="o", ms=3,
                          label=label)  # fmt: skip
        ax.fill_between(x, [100 * r["success_5deg_ci95"][0] for r in rows],
                        [100 * r["success_5deg_ci95"][1] for r in rows],
                        color=line.get_color(), alpha=0.12, lw=0)  # fmt: skip
    if default is not None:
        ax.axvline(default, color="k", ls=":", lw=1, label=f"default ({default:g})")
    ax.set_xlabel(param)
    ax.set_ylabel("success @ 5° (%)")
    ax.grid(alpha=0.3)
    ax.set_title(legend_label(title, 90), fontsize=8)
    ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())
