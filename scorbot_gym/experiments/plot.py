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


def plot_success_vs_occlusion(
    results: Sequence[dict], chance: dict, path: str | os.PathLike, title: str = ""
) -> None:
    """Write the figure to ``path`` (PNG, atomically)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = list(dict.fromkeys(r["estimator"] for r in results))
    many = len(labels) > 4  # legend beside the axes, colours from a 20-colour cycle
    fig, ax = plt.subplots(figsize=(10.5 if many else 7, 4.5), dpi=120)
    colours = plt.get_cmap("tab20" if many else "tab10").colors
    if many:  # tab20 pairs a dark and a light shade of each hue: all ten hues first
        colours = colours[0::2] + colours[1::2]
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
        (line,) = ax.plot(x, y, marker="o", ms=3, label=legend_label(label), color=colour)
        ax.fill_between(x, lo, hi, color=line.get_color(), alpha=0.06 if many else 0.15, lw=0)
        coarse = [
            (xi, r["coarse_success_5deg"], r["success_5deg"])
            for xi, r in zip(x, rows, strict=True)
            if r.get("coarse_success_5deg") is not None
        ]
        if any(c != s for _, c, s in coarse):
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
    ax.set_xlabel("occlusion (% of the object's mask hidden)")
    ax.set_ylabel("success @ 5° (%)")
    ax.set_ylim(-2, 102)
    ax.grid(alpha=0.3)
    ax.set_title(title, fontsize=9)
    if many:
        ax.legend(fontsize=6, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    else:
        ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", bbox_inches="tight")  # the legend beside the axes included
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())


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
