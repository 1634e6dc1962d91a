"""Sweep trials -> one record per (protocol, estimator, occlusion), the chance level, the
stage-ablation table, and each estimator's curve over occlusion in a few numbers.

Success@5° counts an invalid answer as a failure; medians are over valid answers. Errors are
symmetry-aware (:func:`pose.metrics.rotation_error_deg`), so a can's heading is free; because
such objects make image-blind answers look good, every record also reports the figure over the
*asymmetric* objects only (``success_5deg_asymmetric``: symmetry kind "none") and over the
objects without a continuous symmetry (``success_5deg_no_axial``: discrete symmetries such as
a box's half-turn leave a finite ambiguity that any method must resolve). The chance level is
the registered ``chance`` estimator when it is in the sweep, else the constant image-blind
answer "resting face 0, heading 0" scored on the same views (every trial records it).
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Sequence

import numpy as np

from scorbot_gym.evaluation.summary import holm_adjusted, newcombe_paired_diff, wilson_interval

THRESHOLD_DEG = 5.0
CHANCE_ESTIMATOR = "chance"
REFERENCE = "manifold"


def _arr(values) -> np.ndarray:
    return np.array([np.nan if v is None else v for v in values], float)


def _hits(err: np.ndarray) -> np.ndarray:
    """Which views are a success@5deg; an invalid answer (NaN error) is a failure."""
    return np.nan_to_num(err, nan=np.inf) < THRESHOLD_DEG


def _success(err: np.ndarray) -> tuple[int, int]:
    return int(np.sum(_hits(err))), int(err.size)


def _rate(k: int, n: int) -> float | None:
    return round(k / n, 4) if n else None


def _median(x: np.ndarray) -> float | None:
    x = x[np.isfinite(x)]
    return round(float(np.median(x)), 4) if x.size else None


def _pool(trials: Sequence[dict], key: str, symmetries: Sequence[str] | None = None) -> np.ndarray:
    """One view field pooled over the trials of objects with the given symmetry kinds."""
    keep = [t for t in trials if symmetries is None or t["symmetry"] in symmetries]
    return np.concatenate([_arr(t["views"][key]) for t in keep] or [[]])


def summarize_trials(trials: Sequence[dict]) -> dict:
    """The figures of one (protocol, estimator, occlusion) cell, pooled over objects."""
    err = _pool(trials, "rot_err_deg")
    k, n = _success(err)
    ka, na = _success(_pool(trials, "rot_err_deg", ("none",)))
    kx, nx = _success(_pool(trials, "rot_err_deg", ("none", "discrete")))
    kc, nc = _success(_pool(trials, "chance_rot_err_deg"))
    kca, nca = _success(_pool(trials, "chance_rot_err_deg", ("none",)))
    kcx, ncx = _success(_pool(trials, "chance_rot_err_deg", ("none", "discrete")))
    coarse = _pool(trials, "coarse_rot_err_deg")
    valid = np.concatenate([np.asarray(t["views"]["valid"], bool) for t in trials])
    ms = _pool(trials, "ms")
    out = {
        "n": n,
        "n_objects": len({t["object"] for t in trials}),
        "success_5deg": _rate(k, n),
        "success_5deg_ci95": [round(v, 4) for v in wilson_interval(k, n)],
        "success_5deg_asymmetric": _rate(ka, na),
        "success_5deg_asymmetric_ci95": [round(v, 4) for v in wilson_interval(ka, na)]
        if na
        else None,
        "n_asymmetric": na,
        "success_5deg_no_axial": _rate(kx, nx),
        "n_no_axial": nx,
        "median_rot_err_deg": _median(err),
        "valid_rate": _rate(int(valid.sum()), valid.size),
        "median_ms": _median(ms),
        "mean_occlusion_achieved": _median(_pool(trials, "occlusion")),
        "constant_answer_success_5deg": _rate(kc, nc),
        "constant_answer_success_5deg_asymmetric": _rate(kca, nca),
        "constant_answer_success_5deg_no_axial": _rate(kcx, ncx),
    }
    if np.isfinite(coarse).any():  # the estimator reports a pre-refinement answer
        kk, nn = _success(coarse)
        out["coarse_success_5deg"] = _rate(kk, nn)
        out["coarse_success_5deg_ci95"] = [round(v, 4) for v in wilson_interval(kk, nn)]
        kka, nna = _success(_pool(trials, "coarse_rot_err_deg", ("none",)))
        out["coarse_success_5deg_asymmetric"] = _rate(kka, nna)
    return out


def aggregate(trials: Sequence[dict]) -> list[dict]:
    """One record per (protocol, estimator, occlusion), sorted by those keys."""
    cells: dict[tuple, list[dict]] = defaultdict(list)
    for t in trials:
        cells[(t["protocol"], t["estimator"], t["occlusion"])].append(t)
    return [
        {"protocol": p, "estimator": e, "occlusion": o, **summarize_trials(ts)}
        for (p, e, o), ts in sorted(cells.items(), key=lambda kv: (kv[0][0], kv[0][1], kv[0][2]))
    ]


def fit_errors(trials: Sequence[dict]) -> list[dict]:
    """The (protocol, estimator, object) triples whose fit rejected the training views, with the
    estimator's message: their test views count as failures, and a table must say which."""
    seen = {
        (t["protocol"], t["estimator"], t["object"]): t["fit_error"]
        for t in trials
        if t.get("fit_error")
    }
    return [
        {"protocol": p, "estimator": e, "object": o, "error": msg}
        for (p, e, o), msg in sorted(seen.items())
    ]


def selections(trials: Sequence[dict]) -> list[dict]:
    """One row per (protocol, estimator, object) whose model selected a candidate
    (:func:`scorbot_gym.experiments.trial.selection_record`): which one, with the
    cross-validated scores it was chosen by."""
    seen = {
        (t["protocol"], t["estimator"], t["object"]): t["selection"]
        for t in trials
        if t.get("selection")
    }
    return [
        {"protocol": p, "estimator": e, "object": o, **choice}
        for (p, e, o), choice in sorted(seen.items())
    ]


def view_errors(trials: Sequence[dict], decimals: int = 4) -> list[dict]:
    """Every held-out view's rotation error (degrees, symmetry-aware; ``None`` where the
    estimate was invalid: no rotation), one row per (protocol, estimator, object, occlusion),
    the views in the protocol's order. Kept per view, they let a reader find the views behind
    a difference of a few views and compare two estimators view by view (paired tests).

    Errors are truncated (rounded down) to ``decimals``, not rounded to the nearest: the 5deg
    threshold lies on that grid, so every view stays on the side of it where the unrounded
    error, which the summary figures pool, puts it (rounding to the nearest turned a 4.99996deg
    view into a 5.0deg failure, one view off its cell)."""
    scale = 10.0**decimals

    def rounded(v):
        return None if v is None else math.floor(float(v) * scale) / scale

    rows = [
        {
            "protocol": t["protocol"],
            "estimator": t["estimator"],
            "object": t["object"],
            "occlusion": t["occlusion"],
            "rot_err_deg": [rounded(e) for e in t["views"]["rot_err_deg"]],
        }
        for t in trials
    ]
    return sorted(rows, key=lambda r: (r["protocol"], r["estimator"], r["object"], r["occlusion"]))


def paired_differences(rows: Sequence[dict], estimator: str) -> list[dict]:
    """``estimator`` against every other estimator of a sweep on the same views, from the
    report's ``view_errors`` rows: per (protocol, occlusion, other), the success@5deg
    difference ``estimator - other`` with its 95 % interval (Newcombe, paired), how many views
    only one of the two got right, and McNemar's exact p on those. Two estimators scored on the
    same views differ by the views they disagree on, not by two independent intervals.
    ``mcnemar_p_holm`` is that p adjusted (Holm) over the family of one protocol's rows, every
    level against every other estimator: the question "is it behind anything anywhere" asks
    all of them at once."""
    cells: dict[tuple, dict[str, dict[str, list]]] = defaultdict(lambda: defaultdict(dict))
    for r in rows:
        cells[(r["protocol"], r["occlusion"])][r["estimator"]][r["object"]] = r["rot_err_deg"]
    if not any(estimator in by_est for by_est in cells.values()):
        known = sorted({r["estimator"] for r in rows})
        raise ValueError(f"{estimator!r} is not in this sweep; its estimators: {known}")

    def hits(by_object: dict[str, list], objects: list[str]) -> np.ndarray:
        return _hits(np.concatenate([_arr(by_object[o]) for o in objects]))

    out, raw_p = [], []
    for (protocol, occlusion), by_est in sorted(cells.items()):
        if estimator not in by_est:
            continue
        mine = by_est[estimator]
        objects = sorted(mine)
        for other, theirs in sorted(by_est.items()):
            if other == estimator:
                continue
            if sorted(theirs) != objects or any(len(theirs[o]) != len(mine[o]) for o in objects):
                raise ValueError(
                    f"{other!r} was not scored on the same views as {estimator!r} "
                    f"({protocol}, occlusion {occlusion})"
                )
            d = newcombe_paired_diff(hits(mine, objects), hits(theirs, objects))
            raw_p.append(d["mcnemar_p"])
            out.append({
                "protocol": protocol, "occlusion": occlusion, "estimator": estimator,
                "versus": other, "n": sum(len(mine[o]) for o in objects),
                "diff": round(d["diff"], 4), "ci95": [round(v, 4) for v in d["ci95"]],
                "only_estimator": d["only_a"], "only_versus": d["only_b"],
                "mcnemar_p": float(f"{d['mcnemar_p']:.3g}"),
            })  # fmt: skip
    for protocol in {r["protocol"] for r in out}:
        family = [i for i, r in enumerate(out) if r["protocol"] == protocol]
        for i, q in zip(family, holm_adjusted([raw_p[i] for i in family]), strict=True):
            out[i]["mcnemar_p_holm"] = float(f"{q:.3g}")
    return out


def chance_level(results: Sequence[dict]) -> dict:
    """Chance success@5° per occlusion: the ``chance`` estimator's if swept, else the constant
    answer's (identical for every estimator: the same views)."""
    from_est = [r for r in results if r["estimator"].split("(")[0] == CHANCE_ESTIMATOR]
    if from_est:
        src, rows = f"estimator {from_est[0]['estimator']!r}", from_est
        vals = {r["occlusion"]: r["success_5deg"] for r in rows}
        asym = {r["occlusion"]: r["success_5deg_asymmetric"] for r in rows}
    else:
        src = "constant answer: resting face 0, heading 0 (image-blind)"
        vals = {r["occlusion"]: r["constant_answer_success_5deg"] for r in results}
        asym = {r["occlusion"]: r["constant_answer_success_5deg_asymmetric"] for r in results}
    return {
        "source": src,
        "success_5deg": [{"occlusion": o, "value": v} for o, v in sorted(vals.items())],
        "success_5deg_asymmetric": [{"occlusion": o, "value": v} for o, v in sorted(asym.items())],
    }


def curve_summary(results: Sequence[dict], chance: dict) -> list[dict]:
    """Each estimator's success@5° curve over occlusion (the seed's Fig. 3) in a few numbers.

    One row per (protocol, estimator): ``mean_success_5deg`` is the mean over the swept levels
    (for equally spaced levels, the area under the curve divided by its width), also over the
    asymmetric objects only; ``first_at_or_below_chance`` is the lowest swept occlusion at which
    the estimator is no better than the image-blind answer of ``chance`` (``None``: better at
    every level), the point past which the image stops helping. Two rows compare only over the
    same levels, which one sweep guarantees; ``levels`` says which they were."""
    floor = {c["occlusion"]: c["value"] for c in chance["success_5deg"]}
    cells: dict[tuple, list[dict]] = defaultdict(list)
    for r in results:
        cells[(r["protocol"], r["estimator"])].append(r)
    out = []
    for (protocol, estimator), rows in cells.items():
        rows = sorted(rows, key=lambda r: r["occlusion"])

        def mean(key: str, rows=rows) -> float | None:
            vals = [r[key] for r in rows if r.get(key) is not None]
            return round(float(np.mean(vals)), 4) if vals else None

        lost = [
            r["occlusion"]
            for r in rows
            if floor.get(r["occlusion"]) is not None
            and (r["success_5deg"] or 0.0) <= floor[r["occlusion"]]
        ]
        out.append({
            "protocol": protocol, "estimator": estimator,
            "levels": [r["occlusion"] for r in rows],
            "mean_success_5deg": mean("success_5deg"),
            "mean_success_5deg_asymmetric": mean("success_5deg_asymmetric"),
            "first_at_or_below_chance": lost[0] if lost else None,
        })  # fmt: skip
    return out


#: the ``best`` cell of a level where every estimator scored 0
NO_WINNER = "none (every one 0 %)"


def winners(results: Sequence[dict]) -> list[dict]:
    """Per (protocol, occlusion), the estimator with the highest success@5° beside the best
    estimator built on the pose manifold (:func:`builds_on_manifold`), the best baseline and
    the image-blind answer, and whether a baseline wins (``baseline_wins``: an estimator not
    built on the manifold, or the image-blind answer, strictly above every one that is); a
    name is ``None`` where its group's best scored 0: nothing won there. A curve of one method
    cannot say where another beats it; this row does. Views differ between
    levels (the ``clutter`` protocol bins measured occlusion), so ``n`` goes with every row."""
    cells: dict[tuple, list[dict]] = defaultdict(list)
    for r in results:
        cells[(r["protocol"], r["occlusion"])].append(r)
    out = []
    for (protocol, occlusion), rows in sorted(cells.items()):
        scored = [r for r in rows if r["success_5deg"] is not None]
        if not scored:
            continue
        # ties go to the manifold's side, so that a baseline is said to win only above it
        best = max(scored, key=lambda r: (r["success_5deg"], builds_on_manifold(r["estimator"])))
        ours = [r for r in scored if builds_on_manifold(r["estimator"])]
        theirs = [r for r in scored if not builds_on_manifold(r["estimator"])]
        mine = max(ours, key=lambda r: r["success_5deg"]) if ours else None
        base = max(theirs, key=lambda r: r["success_5deg"]) if theirs else None
        blind = scored[0]["constant_answer_success_5deg"]
        top = mine["success_5deg"] if mine else None
        beaten_by = None
        if top is not None:
            if not builds_on_manifold(best["estimator"]) and best["success_5deg"] > top:
                beaten_by = best["estimator"]
            elif blind is not None and blind > top:
                beaten_by = "image-blind answer"
        out.append({
            "protocol": protocol, "occlusion": occlusion, "n": best["n"],
            "best": _leader(best), "best_success_5deg": best["success_5deg"],
            "best_manifold": _leader(mine),
            "manifold_success_5deg": top,
            "best_baseline": _leader(base),
            "baseline_success_5deg": base["success_5deg"] if base else None,
            "image_blind_success_5deg": blind,
            "baseline_wins": beaten_by is not None, "won_by": beaten_by,
        })  # fmt: skip
    return out


def _leader(row: dict | None) -> str | None:
    """The estimator of the highest-scoring ``row``, or ``None`` where it scored 0: where every
    one failed there is no best to name (the first of a tie at 0 is no winner)."""
    return row["estimator"] if row is not None and row["success_5deg"] > 0 else None


def format_winners(rows: Sequence[dict]) -> str:
    """The winners table (empty string for no rows or no manifold composition swept); a level
    where every estimator scored 0 names none."""
    if not rows or all(r["manifold_success_5deg"] is None for r in rows):
        return ""
    lines = [
        "best per level (ok@5 %): overall, best built on the manifold, best baseline, image-blind",
        f"{'occl%':>6}{'n':>6}  {'best':<30}{'ok%':>6}{'manifold':>10}{'baseline':>10}"
        f"{'blind':>7}  note",
    ]
    for r in rows:
        note = f"BASELINE WINS: {r['won_by']}" if r["baseline_wins"] else ""
        lines.append(
            f"{100 * r['occlusion']:>6.0f}{r['n']:>6}  {(r['best'] or NO_WINNER)[:29]:<30}"
            f"{_pct(r['best_success_5deg']):>6}{_pct(r['manifold_success_5deg']):>10}"
            f"{_pct(r.get('baseline_success_5deg')):>10}"
            f"{_pct(r['image_blind_success_5deg']):>7}  {note}"
        )  # fmt: skip
    return "\n".join(lines)


def _family(label: str) -> bool:
    return label.split("(")[0].startswith(REFERENCE)


#: the registered compositions of other estimators, and the parameter naming their parts
COMPOSITIONS = {"fallback": "estimator", "select": "estimators"}


def builds_on_manifold(label: str) -> bool:
    """Whether the estimator ``label`` is the pose manifold's: a ``manifold`` composition, or a
    composition (``fallback``, ``select``) one of whose parts is one. The project's full
    estimators are such compositions (``select(estimators=(L, R, 'pca-rbf', 'chance'))``), so
    a baseline is said to win only where it beats them too. A bare ``fallback`` wraps the
    ``manifold`` (its default part)."""
    from pose.registry import parse_spec

    name, params = parse_spec(label)
    if name.startswith(REFERENCE):
        return True
    if name not in COMPOSITIONS:
        return False
    parts = params.get(COMPOSITIONS[name], REFERENCE if name == "fallback" else ())
    parts = [parts] if isinstance(parts, str) else list(parts)
    return any(isinstance(p, str) and builds_on_manifold(p) for p in parts)


def stage_ablation(results: Sequence[dict]) -> list[dict]:
    """Manifold variants side by side: success@5° per occlusion and its change from the full
    ``manifold`` estimator (or the first variant swept), and over the asymmetric objects only.
    Rows ``<variant> [coarse]`` are the same models' answers before refinement ("refine off"),
    free from one run. Empty when the sweep has no manifold variant."""
    fam = [r for r in results if _family(r["estimator"])]
    if not fam:
        return []
    labels = list(dict.fromkeys(r["estimator"] for r in fam))
    ref = REFERENCE if REFERENCE in labels else labels[0]
    base = {
        (r["protocol"], r["occlusion"]): r["success_5deg"] for r in fam if r["estimator"] == ref
    }
    refined = {  # estimators whose refinement changes some answer: show the coarse rows too
        r["estimator"]
        for r in fam
        if r.get("coarse_success_5deg") is not None
        and r["coarse_success_5deg"] != r["success_5deg"]
    }
    rows = []
    for r in fam:
        variants = [(r["estimator"], r["success_5deg"], r.get("success_5deg_asymmetric"))]
        if r["estimator"] in refined:
            variants.append((f"{r['estimator']} [coarse]", r.get("coarse_success_5deg"),
                             r.get("coarse_success_5deg_asymmetric")))  # fmt: skip
        for label, s, asym in variants:
            b = base.get((r["protocol"], r["occlusion"]))
            rows.append({
                "protocol": r["protocol"], "variant": label, "reference": ref,
                "occlusion": r["occlusion"], "success_5deg": s,
                "delta_vs_reference": None if b is None or s is None else round(s - b, 4),
                "success_5deg_asymmetric": asym,
            })  # fmt: skip
    return rows


def _pct(v) -> str:
    return "-" if v is None else f"{100 * v:5.1f}"


def _show_levels(levels: Sequence[float], cap: int = 7) -> list[float]:
    if len(levels) <= cap:
        return list(levels)
    picks = [0.0, 0.25, 0.5, 0.75, 0.9]
    return [o for o in levels if any(abs(o - p) < 1e-9 for p in picks)] or list(levels[:cap])


def format_results(results: Sequence[dict], chance: dict) -> str:
    """success@5° (95 % CI) per estimator and occlusion, asymmetric-only and chance beside."""
    lines = [f"{'estimator':<28}{'occl%':>6}{'n':>6}{'ok@5%':>8}{'95% CI':>14}{'asym%':>8}"
             f"{'med_deg':>9}{'valid%':>8}{'ms':>8}"]  # fmt: skip
    for r in results:
        lo, hi = r["success_5deg_ci95"]
        med = "-" if r["median_rot_err_deg"] is None else f"{r['median_rot_err_deg']:.2f}"
        ms = "-" if r["median_ms"] is None else f"{r['median_ms']:.1f}"
        lines.append(
            f"{r['estimator'][:27]:<28}{100 * r['occlusion']:>6.0f}{r['n']:>6}"
            f"{_pct(r['success_5deg']):>8}{f'{100 * lo:.0f}-{100 * hi:.0f}':>14}"
            f"{_pct(r['success_5deg_asymmetric']):>8}{med:>9}{_pct(r['valid_rate']):>8}{ms:>8}"
        )
    for key, what in (("success_5deg", "all objects"), ("success_5deg_asymmetric", "asymmetric")):
        vals = chance[key]
        if len({c["value"] for c in vals}) == 1:  # the same views at every level: one number
            text = f"{_pct(vals[0]['value']).strip()} at every level"
        else:
            text = ", ".join(
                f"{100 * c['occlusion']:.0f}%: {_pct(c['value']).strip()}" for c in vals
            )
        lines.append(f"chance, {what} ({chance['source']}): {text}")
    return "\n".join(lines)


def format_stage_ablation(rows: Sequence[dict]) -> str:
    if not rows:
        return ""
    levels = _show_levels(sorted({r["occlusion"] for r in rows}))
    variants = list(dict.fromkeys(r["variant"] for r in rows))
    cell = {(r["variant"], r["occlusion"]): r for r in rows}
    head = f"{'stage ablation (ok@5 %, delta)':<44}" + "".join(
        f"{f'{100 * o:.0f}% occl':>16}" for o in levels
    )
    lines = [head]
    for v in variants:
        cells = []
        for o in levels:
            r = cell.get((v, o))
            if r is None:
                cells.append(f"{'-':>16}")
                continue
            d = r["delta_vs_reference"]
            text = _pct(r["success_5deg"]) + (f" ({100 * d:+.1f})" if d is not None else "")
            cells.append(f"{text:>16}")
        lines.append(f"{v[:43]:<44}" + "".join(cells))
    return "\n".join(lines)


def format_selections(rows: Sequence[dict]) -> str:
    """Per model-selecting estimator, the candidate it chose for each object, with the
    cross-validated success@5° that chose it."""
    lines = []
    for estimator in dict.fromkeys(r["estimator"] for r in rows):
        lines.append(f"{estimator} chose (cross-validated ok@5 % on the training views):")
        for r in rows:
            if r["estimator"] == estimator:
                cv = r["cv_success_5deg"][r["candidates"].index(r["selected"])]
                lines.append(f"  {r['object']:<18}{_pct(cv):>6}  {r['selected']}")
    return "\n".join(lines)


def format_curves(rows: Sequence[dict]) -> str:
    """The curve summary as a text table (empty string for no rows)."""
    if not rows:
        return ""
    lo, hi = min(rows[0]["levels"]), max(rows[0]["levels"])
    lines = [f"curves over {len(rows[0]['levels'])} levels, {100 * lo:.0f}-{100 * hi:.0f} % "
             "occlusion: mean ok@5 % (all / asymmetric), first level at or below chance",
             f"{'estimator':<44}{'mean%':>7}{'asym%':>7}{'<=chance':>10}"]  # fmt: skip
    for r in rows:
        first = r["first_at_or_below_chance"]
        at = "never" if first is None else f"{100 * first:.0f} %"
        lines.append(
            f"{r['estimator'][:43]:<44}{_pct(r['mean_success_5deg']):>7}"
            f"{_pct(r['mean_success_5deg_asymmetric']):>7}{at:>10}"
        )
    return "\n".join(lines)


def report_tables(report: dict) -> list[str]:
    """The text tables printed after a sweep's results (curves, stage ablation, selections,
    paired comparison), the empty ones left out: the CLI and the benchmark print the same."""
    tables = (
        format_curves(report["curves"]),
        format_winners(report.get("winners", [])),
        format_stage_ablation(report["stage_ablation"]),
        format_selections(report["selections"]),
        format_paired(report.get("paired", [])),
    )
    return [t for t in tables if t]


def format_paired(rows: Sequence[dict]) -> str:
    """The paired comparison as a text table (empty string for no rows)."""
    if not rows:
        return ""
    lines = [f"paired: {rows[0]['estimator']} against each estimator, on the same views",
             f"{'protocol':16s} {'occ':>5s} {'diff':>7s} {'95 % CI':>17s} {'only it':>8s} "
             f"{'only vs':>8s} {'McNemar p':>10s} {'Holm p':>7s}  versus"]  # fmt: skip
    for r in rows:
        lo, hi = r["ci95"]
        holm = f"{r['mcnemar_p_holm']:.3g}" if "mcnemar_p_holm" in r else "-"
        lines.append(
            f"{r['protocol']:16s} {100 * r['occlusion']:4.0f}% {100 * r['diff']:+6.1f} "
            f"({100 * lo:+6.1f}, {100 * hi:+6.1f}) {r['only_estimator']:8d} "
            f"{r['only_versus']:8d} {r['mcnemar_p']:10.3g} {holm:>7s}  {r['versus']}"
        )
    return "\n".join(lines)
