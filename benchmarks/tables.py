"""Rewrite the result tables of the READMEs from the committed benchmark JSON.

Every table (or headline sentence) that quotes a benchmark file sits between two markers,
``<!-- table:NAME -->`` and ``<!-- /table -->``; this script replaces what lies between them
with :data:`TABLES` ``[NAME]`` rendered from ``benchmarks/results/``. So a rerun benchmark updates
its tables with one command, and a figure cannot drift from its file:
``tests/test_benchmark_tables.py`` requires the committed READMEs to equal what this script
writes.

    python benchmarks/tables.py            # rewrite README.md and benchmarks/README.md
    python benchmarks/tables.py --check    # exit 1, naming the stale blocks, if they differ
"""

from __future__ import annotations

import argparse
import re
import sys
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"
READMES = (ROOT / "README.md", ROOT / "benchmarks" / "README.md")
BLOCK = re.compile(r"(<!-- table:([\w-]+) -->\n)(.*?)(<!-- /table -->)", re.S)
PROTOCOLS = (
    "top-resting",
    "side-turntable",
    "tilted",
    "sparse-headings",
    "overview",
    "cross-camera",
)


def read(name: str) -> dict:
    from pose.fileio import read_json

    return read_json(RESULTS / name)


def pct(x: float | None, digits: int = 1) -> str:
    return "—" if x is None else f"{100 * x:.{digits}f} %"


def num(x: float | None) -> str:
    """A rate in percent with one decimal; "—" where the file has none (nothing answered)."""
    return "—" if x is None else f"{100 * x:.1f}"


def ci(pair, digits: int = 1) -> str:
    lo, hi = pair
    dash = "–" if lo >= 0 else " to "  # "−9.0 to −2.1", not "−9.0–−2.1"
    return f"({100 * lo:.{digits}f}{dash}{100 * hi:.{digits}f})"


def failures(causes: dict) -> str:
    return ", ".join(f"{n} {c}" for c, n in causes.items() if n) or "none"


def table(head: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(head) + " |", "| " + " | ".join("---" for _ in head) + " |"]
    return "\n".join(lines + ["| " + " | ".join(r) + " |" for r in rows]) + "\n"


def short(spec: str, names: dict[str, str]) -> str:
    """An estimator spec as a table cell: a short name where the section defines one."""
    return names.get(spec, f"`{spec}`")


# ---- closed loop and policies -------------------------------------------------------------


#: the blind arms of ``closed_loop.json``, each found by its configuration (not its label, which
#: lives in closed_loop.py alone): (words in the headline, config keys and values, what to run)
BLIND_ARMS = (
    ("rotation-blind (a constant rotation) at the image's position",
     {"pose": "manifold", "estimator": "chance"},
     "rotation-blind (image position, constant rotation)"),
    ("at the true position", {"pose": "oracle_position"},
     "rotation-blind (true position, constant rotation)"),
    ("image-blind (one constant pose, the identity given)", {"pose": "constant"},
     "image-blind (constant pose, identity given)"),
)  # fmt: skip


def _arm_by_config(arms: dict, want: dict) -> str | None:
    """The label of the undisturbed arm whose configuration has ``want``'s values."""
    for label, arm in arms.items():
        config = arm.get("config", {})
        if config.get("disturbance") is None and all(config.get(k) == v for k, v in want.items()):
            return label
    return None


def headline_closed_loop() -> str:
    d = read("closed_loop.json")
    arms = d["arms"]
    blind = [(words, _arm_by_config(arms, want), run) for words, want, run in BLIND_ARMS]
    missing = [k for k in ("manifold", "oracle") if k not in arms]
    missing += [run for _, label, run in blind if label is None]
    if missing:  # the headline states the blind levels beside the estimator, or nothing
        sys.exit(
            f"closed_loop.json lacks the arms {missing}: run benchmarks/closed_loop.py --arms "
            f"'{';'.join(missing)}' --out PART.json and --merge it"
        )
    a, o = arms["manifold"], arms["oracle"]
    levels = ", ".join(f"{words} {pct(arms[label]['success_rate'])}" for words, label, _ in blind)
    names = ", ".join(f"`{label}`" for _, label, _ in blind)
    return (
        f"**{pct(a['success_rate'])}** of {a['episodes']} seeded grasps "
        f"(95 % CI {ci(a['success_rate_ci95'])[1:-1]}) with the pose estimated from the camera "
        f"images alone (background subtraction, recognition on `top` + `side`, pose manifold, "
        f"table-top prior; "
        f"whole catalogue, scripted controller, seeds from {d['seed']}); with the true pose "
        f"(the upper bound) {pct(o['success_rate'])}; {levels} "
        f"(`benchmarks/results/closed_loop.json`, arms `manifold`, `oracle`, {names}).\n"
    )


#: the closed-loop run with the resting-view pose models (the default before the tilted ones)
RESTING_CLOSED_LOOP = "closed_loop_resting_models.json"
#: its perturbation run (``closed_loop.py --perturbations``)
RESTING_PERTURBATIONS = "closed_loop_perturbations_resting_models.json"


def closed_loop_arms(name: str = "closed_loop.json") -> str:
    d = read(name)
    rows = []
    for label, a in d["arms"].items():
        valid = a.get("perception", {}).get("valid_rate")
        rows.append(
            [
                label,
                str(a["episodes"]),
                f"{pct(a['success_rate'])} {ci(a['success_rate_ci95'])}",
                failures(a["failure_causes"]),
                pct(valid, 0) if valid is not None else "—",
            ]
        )
    return table(["arm", "episodes", "success (95 % CI)", "failures", "valid estimates"], rows)


def closed_loop_robustness() -> str:
    d = read("closed_loop.json")["robustness"]
    rows = []
    for axis, unit in (("yaw", "heading σ (°)"), ("pos", "position σ (cm)")):
        points = d[axis]
        rows.append(
            [
                unit,
                " / ".join(f"{p['sigma']:g}" for p in points),
                " / ".join(f"{100 * p['success_rate']:.0f}" for p in points),
            ]
        )
    return table(["`noisy_oracle` noise", "σ", "success (%)"], rows)


def closed_loop_perturbations() -> str:
    d = read("closed_loop_perturbations.json")
    before = read(RESTING_PERTURBATIONS)["arms"]  # the same run with the resting-view models
    rows = []
    for label in d["perturbations"]:
        a = d["arms"][label]
        p = a["perception"]
        rows.append(
            [
                f"`{label}`",
                f"{pct(a['success_rate'])} {ci(a['success_rate_ci95'])}",
                pct(before[label]["success_rate"]) if label in before else "–",
                failures(a["failure_causes"]),
                f"{pct(p['valid_rate'])} / {pct(p['first_estimate_valid_rate'])}",
                pct(p["recognition_accuracy"]),
                f"{p['median_pos_err_cm']:.2f} cm / {p['median_rot_err_deg']:.2f}°",
            ]
        )
    return table(
        [
            "perturbation",
            "success (95 % CI)",
            "with the resting-view models",
            "failures",
            "valid estimates (all steps / first)",
            "recognition",
            "median position / rotation error",
        ],
        rows,
    )


def policy_name(policy: str) -> str:
    """A policy as the comparison names it: ``scripted``, ``rl``, or its run's folder."""
    parts = Path(policy).parts
    return "/".join(parts[-3:]) if len(parts) > 1 else policy


def _compare_rows(d: dict) -> list[list[str]]:
    by = {(r["policy"], r["pose"]): r for r in d["results"]}
    policies = list(dict.fromkeys(r["policy"] for r in d["results"]))
    first = policies[0]
    rows = []
    for pose in dict.fromkeys(r["pose"] for r in d["results"]):
        for other in policies[1:]:
            diff = next(x for x in d["differences"] if x["pose"] == pose and x["a"] == other)
            a, b = by[(first, pose)], by[(other, pose)]
            rows.append(
                [
                    f"`{pose}`",
                    f"{pct(a['success_rate'])} {ci(a['ci95'])}",
                    f"`{policy_name(other)}` {pct(b['success_rate'])} {ci(b['ci95'])}",
                    f"{100 * diff['diff']:+.1f} pts {ci(diff['ci95'])}",
                    f"{diff['mcnemar_p']:.2g}",
                ]
            )
    return rows


def compare_table(name: str) -> Callable[[], str]:
    def render() -> str:
        d = read(name)
        head = [
            "pose",
            f"`{d['results'][0]['policy']}` (95 % CI)",
            "other policy (95 % CI)",
            "paired difference (95 % CI)",
            "McNemar p",
        ]
        return table(head, _compare_rows(d))

    return render


def compare_arms() -> str:
    """``compare.json``, one row per arm (``scorbot_gym.evaluation.compare.markdown_table``)."""
    from scorbot_gym.evaluation.compare import markdown_table

    return markdown_table(read("compare.json"))


def _condition_words(cond: dict) -> str:
    """``with the true pose`` / ``with heading noise σ 20°`` / ... for a compare condition."""
    if cond["source"] == "oracle":
        return "with the true pose"
    if cond.get("estimator") == "chance":  # the manifold source, but not its estimator
        return (
            "at the rotation-blind chance level (the same masks and recognised identity: the "
            "position from the images, a constant rotation)"
        )
    if cond["source"] == "manifold" and cond.get("identity") == "recognize":
        return (
            "with the pose-manifold estimator and no privileged input (background masks, "
            "recognised identity)"
        )
    if cond["source"] != "noisy_oracle":
        return f"with the `{cond['label']}` pose"
    pos, yaw = cond["noise_pos_m"], cond["noise_yaw_deg"]
    noise = [f"position σ {100 * pos:g} cm" if pos else "", f"heading σ {yaw:g}°" if yaw else ""]
    return "with pose noise " + " and ".join(n for n in noise if n)


def headline_compare() -> str:
    """Every policy against the reference under every pose condition of ``compare.json``."""
    d = read("compare.json")
    by = {(r["policy"], r["pose"]): r for r in d["results"]}
    ref = d["reference"]
    sentences = []
    for cond in d["conditions"]:
        pose, r0 = cond["label"], by[(ref, cond["label"])]
        parts = [f"`{ref}` **{pct(r0['success_rate'])}** {ci(r0['ci95'])}"]
        for r in d["results"]:
            if r["pose"] != pose or r["policy"] == ref:
                continue
            diff = r["vs_reference"]
            parts.append(
                f"`{r['label']}` **{pct(r['success_rate'])}** {ci(r['ci95'])} "
                f"(paired difference {100 * diff['diff']:+.1f} points, 95 % CI "
                f"{ci(diff['ci95'])[1:-1]}, McNemar p = {diff['mcnemar_p']:.2g})"
            )
        words = _condition_words(cond)
        sentences.append(f"{words[0].upper()}{words[1:]}: " + ", ".join(parts))
    objects = "whole catalogue" if d["objects"] is None else ", ".join(d["objects"])
    return (
        f"Over {d['episodes']} paired episodes (seeds {d['seeds'][0]}–{d['seeds'][-1]}, "
        f"{objects}, {d['action_type']} actions). "
        + ". ".join(sentences)
        + " (`benchmarks/results/compare.json`).\n"
    )


def rl_training() -> str:
    d = read("rl_training.json")
    rows = []
    for arm, run in d["arms"].items():
        curve = " → ".join(
            f"{100 * p['success_rate']:.0f} % at {p['timesteps']:,}" for p in run["curve"]
        )
        rows.append([arm, f"{run['timesteps']:,}", f"{run['train_wall_s']:,.0f} s", curve])
    return table(["arm", "env steps", "training wall time", "success along the curve"], rows)


# ---- environment --------------------------------------------------------------------------


def _render(settings: dict) -> str:
    """An env's render settings as a table cell: MSAA, shadows, reflective materials."""
    msaa = settings.get("msaa_samples")
    parts = ["MSAA ?" if msaa is None else (f"MSAA {msaa}×" if msaa else "no MSAA")]
    parts.append("shadows" if settings.get("shadows_rendered") else "no shadows")
    reflective = settings.get("reflective_materials")
    parts.append(
        "reflections ?"
        if reflective is None
        else (f"{reflective} reflective materials" if reflective else "no reflections")
    )
    return ", ".join(parts)


def env_step() -> str:
    d = read("env_step.json")
    rows = []
    for setting, label in (("no_images", "no images"), ("camera_320x240", "320 × 240 RGB")):
        for env, r in d["results"].get(setting, {}).items():
            if "error" in r:
                continue
            cpu = r["steps_per_cpu_second_runs"]
            rows.append(
                [
                    label,
                    env,
                    f"{r['steps_per_cpu_second_median']:.0f} ({min(cpu):.0f}–{max(cpu):.0f})",
                    f"{r['steps_per_second_median']:.0f}",
                    f"{r['sim_seconds_per_wall_second_median']:.2g}",
                    _render(r["render_settings"]) if setting != "no_images" else "—",
                ]
            )
    head = ["setting", "env", "steps / CPU s (range)", "steps/s (wall)", "sim s / wall s",
            "rendering"]  # fmt: skip
    return table(head, rows)


def env_step_ratios() -> str:
    """The paired ratios of ``env_step.json`` (``ratios``): per CPU second, median and range."""
    d = read("env_step.json")
    rows = []
    for r in d["ratios"]:
        if not r["pairs"]:
            continue
        rs = r["render_settings"]
        rendering = (
            "—"
            if r["setting"] == "no_images"
            else f"{_render(rs['numerator'])} / {_render(rs['denominator'])}"
        )
        rows.append(
            [
                r["comparison"],
                "no images" if r["setting"] == "no_images" else "320 × 240 RGB",
                str(r["pairs"]),
                f"**{r['cpu_ratio_median']:.2f}×** ({r['cpu_ratio_min']:.2f}–"
                f"{r['cpu_ratio_max']:.2f})",
                f"{r['wall_ratio_median']:.2f}×",
                rendering,
            ]
        )
    head = ["ratio", "setting", "pairs", "per CPU second, median (range)", "wall, median",
            "rendering (numerator / denominator)"]  # fmt: skip
    return table(head, rows)


# ---- pose estimation sweeps ---------------------------------------------------------------


def _cell(r: dict, with_ci: bool) -> str:
    text = pct(r["success_5deg"])
    if with_ci:
        text += f" {ci(r['success_5deg_ci95'], 0)}"
    asym = r.get("success_5deg_asymmetric")
    return text + ("" if asym is None else f" [{100 * asym:.0f}]")


def sweep_table(
    suffix: str,
    protocols: tuple[str, ...] = PROTOCOLS,
    names: dict[str, str] | None = None,
    cost: bool = False,
) -> Callable[[], str]:
    """success@5° [asymmetric banana] per (protocol, estimator) and occlusion, from
    ``pose_ablation_{protocol}{suffix}.json.gz``; the 95 % CI in the first column. ``cost``
    adds the share of views answered and the median ``predict`` wall time at the first level
    (two workers sharing two cores: not a single-core figure)."""
    names = names or {}

    def render() -> str:
        rows, levels = [], None
        for protocol in protocols:
            d = read(f"pose_ablation_{protocol}{suffix}.json.gz")
            levels = d["spec"]["occlusions"]
            cells = {(r["estimator"], r["occlusion"]): r for r in d["results"]}
            for est in d["spec"]["estimators"]:
                first = cells[(est, levels[0])]
                extra = [pct(first["valid_rate"], 0), f"{first['median_ms']:.1f}"] if cost else []
                rows.append(
                    [f"`{protocol}`", short(est, names)]
                    + [_cell(cells[(est, o)], i == 0) for i, o in enumerate(levels)]
                    + extra
                )
        head = ["protocol", "estimator"] + [f"{100 * o:.0f} %" for o in levels]
        if cost:
            head += [f"valid at {100 * levels[0]:.0f} %", f"median ms at {100 * levels[0]:.0f} %"]
        return table(head, rows)

    return render


SELECT_NAMES = {
    "manifold-pnp(keypoints__upscale=2, matcher__min_inliers=6, matcher__n_candidates=8, "
    "refiner__correspondences='ratio+global', refiner__keep_margin=0.0)": "L",
    "manifold-pnp(keypoints__upscale=2, matcher__min_inliers=6, "
    "refiner__correspondences='ratio+global')": "R",
}


def _select_names(spec_estimators: list[str]) -> dict[str, str]:
    names = dict(SELECT_NAMES)
    for e in spec_estimators:
        if e.startswith("select("):
            names[e] = "**`select(L, R, pca-rbf, chance)`**"
        elif e.startswith("fallback(estimator='select("):
            names[e] = "`fallback(select(…), pca-nn)`"
    return names


def select_table() -> str:
    names = _select_names(read("pose_ablation_top-resting_select.json.gz")["spec"]["estimators"])
    return sweep_table("_select", names=names)()


def headline_ablation() -> str:
    d = read("pose_ablation_side-turntable_select.json.gz")
    sel = next(e for e in d["spec"]["estimators"] if e.startswith("select("))
    cells = {(r["estimator"], r["occlusion"]): r for r in d["results"]}
    zero, half = cells[(sel, 0.0)], cells[(sel, 0.5)]
    blind = d["chance"]["success_5deg"][0]["value"]
    return (
        f"On `side-turntable` (trained and tested on the `side` camera, headings every 10°; "
        f"11 objects, {zero['n']} held-out views per cell, 320 × 240, seed 0), the per-object "
        f"selection `select(L, R, pca-rbf, chance)` scores **{pct(zero['success_5deg'])}** "
        f"success@5° {ci(zero['success_5deg_ci95'])} unoccluded and "
        f"**{pct(half['success_5deg'])}** {ci(half['success_5deg_ci95'])} at 50 % occlusion; "
        f"the image-blind answer scores {pct(blind)} "
        f"(`benchmarks/results/pose_ablation_side-turntable_select.json.gz`).\n"
    )


def fig3_curves() -> str:
    """Each estimator's curve over 0–95 % as mean success / first level at or below chance
    [mean over the asymmetric banana], from each ``_fig3`` file's ``curves``."""
    per = {p: read(f"pose_ablation_{p}_fig3.json.gz") for p in PROTOCOLS}
    estimators = per[PROTOCOLS[0]]["spec"]["estimators"]
    names = _select_names(estimators)
    rows = []
    for est in estimators:
        row = [short(est, names)]
        for p in PROTOCOLS:
            c = next(c for c in per[p]["curves"] if c["estimator"] == est)
            first = c["first_at_or_below_chance"]
            first = "never" if first is None else f"{100 * first:.0f}"
            asym = c.get("mean_success_5deg_asymmetric")
            mean = f"{100 * c['mean_success_5deg']:.1f}"
            row.append(
                f"{mean} [{100 * asym:.1f}]"
                if est == "chance"
                else f"{mean} / {first} [{100 * asym:.1f}]"
            )
        rows.append(row)
    return table(["estimator"] + [f"`{p}`" for p in PROTOCOLS], rows)


def stage_ablation() -> str:
    """Coarse success@5° at 0 / 50 % [banana at 0 %] of each manifold variant on every
    protocol, from each ``_stages`` file's ``stage_ablation`` rows (``[coarse]``: refine off)."""
    per = {p: read(f"pose_ablation_{p}_stages.json.gz")["stage_ablation"] for p in PROTOCOLS}
    variants = [r["variant"] for r in per[PROTOCOLS[0]] if r["occlusion"] == 0.0]
    coarse = [v for v in variants if v.endswith(" [coarse]")]
    rows = []
    for v in coarse + ["manifold"]:
        row = [f"`{v.removesuffix(' [coarse]')}`" if v in coarse else "every variant, refined"]
        for p in PROTOCOLS:
            # a [coarse] row is left out where refinement changed no answer: the refined row
            cells = {r["occlusion"]: r for r in per[p] if r["variant"] == v} or {
                r["occlusion"]: r for r in per[p] if r["variant"] == v.removesuffix(" [coarse]")
            }
            a, b = cells[0.0], cells[0.5]
            row.append(
                f"{num(a['success_5deg'])} / {num(b['success_5deg'])}"
                f" [{num(a['success_5deg_asymmetric'])}]"
            )
        rows.append(row)
    return table(["variant (coarse answer)"] + [f"`{p}`" for p in PROTOCOLS], rows)


def view_perturbations() -> str:
    d = read("pose_ablation_side-turntable_perturbations.json.gz")
    ests = d["spec"]["estimators"]
    names = _select_names(ests)
    levels = sorted({r["occlusion"] for r in d["results"]})
    cells = {(r["perturbation"], r["estimator"], r["occlusion"]): r for r in d["results"]}
    head = ["perturbation"] + [f"{short(e, names)} {100 * o:.0f} %" for e in ests for o in levels]
    rows = [
        [f"`{p}`"] + [_cell(cells[(p, e, o)], True) for e in ests for o in levels]
        for p in d["perturbations"]
    ]
    return table(head, rows)


def keep_margin() -> str:
    d = read("keep_margin_seed1.json")
    cells = list(dict.fromkeys((r["protocol"], r["occlusion"]) for r in d["results"]))
    rows = []
    for m in d["margins"]:
        by = {(r["protocol"], r["occlusion"]): r for r in d["results"] if r["keep_margin"] == m}
        rows.append([f"{m:g}"] + [f"{100 * by[c]['success_5deg']:.1f}" for c in cells])
    return table(["`keep_margin` (px²)"] + [f"`{p}` {100 * o:.0f} %" for p, o in cells], rows)


def selection_choices() -> str:
    d = read("selection_choices.json")
    names = {**SELECT_NAMES, "pca-rbf": "`pca-rbf`", "chance": "`chance`"}
    by: dict[str, dict[str, list[str]]] = {}
    for r in d["choices"]:
        chosen = names.get(r["selected"], f"`{r['selected']}`")
        by.setdefault(r["protocol"], {}).setdefault(chosen, []).append(r["object"])
    rows = [
        [f"`{p}`", "; ".join(f"{c}: {', '.join(objs)}" for c, objs in by[p].items())] for p in by
    ]
    return table(["protocol", "candidate chosen: objects"], rows)


TABLES: dict[str, Callable[[], str]] = {
    "headline-closed-loop": headline_closed_loop,
    "headline-compare": headline_compare,
    "headline-ablation": headline_ablation,
    "closed-loop": closed_loop_arms,
    "closed-loop-robustness": closed_loop_robustness,
    "closed-loop-resting": lambda: closed_loop_arms(RESTING_CLOSED_LOOP),
    "closed-loop-perturbations": closed_loop_perturbations,
    "compare": compare_arms,
    "compare-noise-once": compare_table("compare_noise_once.json"),
    "compare-heldout": compare_table("compare_heldout_objects.json"),
    "compare-heldout-training": compare_table("compare_heldout_training_objects.json"),
    "rl-training": rl_training,
    "env-step": env_step,
    "env-step-ratios": env_step_ratios,
    "fig3-curves": fig3_curves,
    "select": select_table,
    "selection-choices": selection_choices,
    "stages": stage_ablation,
    "view-perturbations": view_perturbations,
    "all-estimators": sweep_table("_all", protocols=PROTOCOLS),
    "pnp": sweep_table("_pnp", protocols=PROTOCOLS[:4]),
    "upscale": sweep_table("_upscale", cost=True),
    "fallback": sweep_table("_fallback", cost=True),
    "global": sweep_table("_global", cost=True),
    "keep-margin": keep_margin,
}


def render(text: str) -> str:
    """``text`` with every marked block replaced by its table; unknown names are an error."""

    def fill(m: re.Match) -> str:
        name = m.group(2)
        if name not in TABLES:
            raise ValueError(f"unknown table {name!r}; known: {', '.join(TABLES)}")
        return m.group(1) + TABLES[name]() + m.group(4)

    return BLOCK.sub(fill, text)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--check", action="store_true", help="only report stale files, exit 1")
    args = ap.parse_args(argv)
    stale = []
    for path in READMES:
        old = path.read_text()
        new = render(old)
        if new != old:
            stale.append(path)
            if not args.check:
                path.write_text(new)
    verb = "stale" if args.check else "rewrote"
    for path in stale:
        print(f"{verb}: {path.relative_to(ROOT)}")
    return 1 if args.check and stale else 0


if __name__ == "__main__":
    sys.exit(main())
