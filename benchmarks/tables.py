"""Rewrite the result tables of the READMEs from the committed benchmark JSON.

Every table (or headline sentence) that quotes a benchmark file sits between two markers,
``<!-- table:NAME -->`` and ``<!-- /table -->``; this script replaces what lies between them
with :data:`TABLES` ``[NAME]`` rendered from ``benchmarks/results/``: in ``benchmarks/README.md``
every result section's table and its "Main run" conditions line (episodes, seeds, machine, the
configs beside it), and the index of result files; in ``README.md`` the headline figures. A
result file holds a script's main run and its variants as named configs
(:func:`pose.fileio.read_result`). So a rerun benchmark updates
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


def read(name: str, config: str | None = None) -> dict:
    """The default run of ``results/NAME`` or, given ``config``, its variant of that name."""
    from pose.fileio import read_result

    return read_result(RESULTS / name, config)


#: the pose-ablation sweeps, one config per ``{protocol}{suffix}`` (``pose_ablation.py``)
ABLATION = "pose_ablation.json.gz"


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


#: RolloutConfig fields added after some arms were run, at the value those arms ran with
CONFIG_DEFAULTS = {"estimator": "manifold", "resting_hypothesis": False, "calibration": "none"}


def _arm_by_config(arms: dict, want: dict) -> str | None:
    """The label of the undisturbed arm whose configuration has ``want``'s values."""
    for label, arm in arms.items():
        config = arm.get("config", {})
        have = {**CONFIG_DEFAULTS, **config}  # keys an older run did not record yet
        if have.get("disturbance") is None and all(have.get(k) == v for k, v in want.items()):
            return label
    return None


#: the rollout default's configuration (the arm the headline quotes), the default it replaced
#: on 2026-11-28 (the cameras as calibrated) and the per-estimate prior of before 2026-11-27
DEFAULT_ARM = {"pose": "manifold", "support": "table_memory", "estimator": "manifold",
               "recognizer": "appearance", "pose_model": None, "fallback_cameras": [],
               "resting_hypothesis": False, "calibration": "arm"}  # fmt: skip
UNCALIBRATED_ARM = {**DEFAULT_ARM, "calibration": "none"}
PER_ESTIMATE_ARM = {**UNCALIBRATED_ARM, "support": "table", "recognizer": "flr+appearance"}


def headline_closed_loop() -> str:
    d = read("closed_loop.json")
    arms = d["arms"]
    blind = [(words, _arm_by_config(arms, want), run) for words, want, run in BLIND_ARMS]
    default = _arm_by_config(arms, DEFAULT_ARM)
    uncalibrated = _arm_by_config(arms, UNCALIBRATED_ARM)
    before = _arm_by_config(arms, PER_ESTIMATE_ARM)
    wanted = (("the default's arm (calibration arm)", default),
              ("the arm with the cameras as calibrated (calibration none)", uncalibrated),
              ("the per-estimate prior's arm (support table)", before))  # fmt: skip
    missing = [k for k, label in wanted if not label]
    missing += [k for k in ("oracle",) if k not in arms]
    missing += [run for _, label, run in blind if label is None]
    if missing:  # the headline states the blind levels beside the estimator, or nothing
        sys.exit(
            f"closed_loop.json lacks the arms {missing}: run benchmarks/closed_loop.py --arms "
            f"'{';'.join(missing)}' --out PART.json, then --merge it with the file's main run "
            "(--out benchmarks/results/closed_loop.json --overwrite)"
        )
    a, o, b, u = arms[default], arms["oracle"], arms[before], arms[uncalibrated]
    levels = ", ".join(f"{words} {pct(arms[label]['success_rate'])}" for words, label, _ in blind)
    names = ", ".join(f"`{label}`" for _, label, _ in blind)
    return (
        f"**{pct(a['success_rate'])}** of {a['episodes']} seeded grasps "
        f"(95 % CI {ci(a['success_rate_ci95'])[1:-1]}) with the pose estimated from the camera "
        f"images alone (background subtraction, recognition by appearance, pose manifold, "
        f"table-top prior held per episode, cameras re-calibrated from the arm; "
        f"whole catalogue, scripted controller, seeds from {d['seed']}); with the cameras as "
        f"calibrated (the default until 2026-11-28) {pct(u['success_rate'])}; with the "
        f"defaults before 2026-11-27 (the prior judged per estimate, FLR's shortlist) "
        f"{pct(b['success_rate'])}; with the true pose "
        f"(the upper bound) {pct(o['success_rate'])}; {levels} "
        f"(`benchmarks/results/closed_loop.json`, arms `{default}`, `{uncalibrated}`, "
        f"`{before}`, `oracle`, {names}).\n"
    )


#: the configs of closed_loop.json that pair the default against the defaults it replaced and
#: the resting-view models on fresh seeds (issue 51), and, beside the second, the first arm
#: calibration (switched on by the correction at the placement region's corners), which the
#: default replaced on the same seeds (its label is the default's)
FRESH_SEEDS = ("fresh_seeds", "fresh_seeds_64000")
REGION_LATCH = ("fresh_seeds_64000_region_latch", "first arm calibration (latch at the region)")


def closed_loop_paired() -> str:
    """The arms of the fresh-seed runs, each paired episode by episode with the default on
    the same seeds (``failed`` seeds: the others succeeded): Δ, its Newcombe interval and
    McNemar's p."""
    from scorbot_gym.evaluation.summary import newcombe_paired_diff

    rows = []
    for config in FRESH_SEEDS:
        d = read("closed_loop.json", config)
        arms = dict(d["arms"])
        if config == FRESH_SEEDS[-1]:
            (previous,) = read("closed_loop.json", REGION_LATCH[0])["arms"].values()
            arms[REGION_LATCH[1]] = previous
        seeds = [str(d["seed"] + i) for i in range(d["episodes_per_arm"])]
        ok = {label: [s not in a["failed"] for s in seeds] for label, a in arms.items()}
        ref = _arm_by_config(d["arms"], DEFAULT_ARM)
        for label, a in arms.items():
            fails = ", ".join(f"{s} {o} {c}" for s, (o, c) in a["failed"].items()) or "none"
            if label == ref:
                vs = "(the default)"
            else:
                diff = newcombe_paired_diff(ok[label], ok[ref])
                lo, hi = diff["ci95"]
                vs = (
                    f"{100 * diff['diff']:+.1f} ({100 * lo:+.1f} to {100 * hi:+.1f}), "
                    f"{diff['only_a']} vs {diff['only_b']}, p = {diff['mcnemar_p']:.2f}"
                )
            rate = f"{pct(a['success_rate'])} {ci(a['success_rate_ci95'])}"
            rows.append([f"{seeds[0]}–{seeds[-1][-3:]}", label, rate, fails, vs])
    head = ["seeds", "arm", "success (95 % CI)", "failed (seed, object, cause)",
            "Δ vs default, points (95 % CI), discordant, McNemar p"]  # fmt: skip
    return table(head, rows)


#: configs of closed_loop.json: the perturbation run (``closed_loop.py --perturbations``) and its
#: twins with the resting-view pose models (the default before the tilted ones) and later defaults
PERTURBATIONS = "perturbations"
RESTING_PERTURBATIONS = "perturbations_resting_models"
HELD_PERTURBATIONS = "perturbations_defaults"
#: the perturbation run with today's defaults (``--perturbation-calibration arm``), and the
#: calibration error alone on fresh seeds, as calibrated and re-calibrated from the arm
CALIBRATED_PERTURBATIONS = "perturbations_calibration"
FRESH_UNCALIBRATED = "calibration_error_fresh_seeds"
FRESH_CALIBRATED = "calibration_error_fresh_seeds_arm"


def closed_loop_arms() -> str:
    """The arms of the main run."""
    d = read("closed_loop.json")
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
    d = read("closed_loop.json", PERTURBATIONS)
    # the same run with the resting-view models
    before = read("closed_loop.json", RESTING_PERTURBATIONS)["arms"]
    held = read("closed_loop.json", HELD_PERTURBATIONS)["arms"]  # the defaults of 2026-11-27
    today = read("closed_loop.json", CALIBRATED_PERTURBATIONS)["arms"]  # since 2026-11-28
    rows = []
    for label in d["perturbations"]:
        a = d["arms"][label]
        p = a["perception"]
        rows.append(
            [
                f"`{label}`",
                f"{pct(a['success_rate'])} {ci(a['success_rate_ci95'])}",
                pct(before[label]["success_rate"]) if label in before else "–",
                pct(held[label]["success_rate"]) if label in held else "–",
                pct(today[label]["success_rate"]) if label in today else "–",
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
            "with the defaults of 2026-11-27",
            "with today's defaults (+ arm calibration)",
            "failures",
            "valid estimates (all steps / first)",
            "recognition",
            "median position / rotation error",
        ],
        rows,
    )


def closed_loop_calibration_fresh() -> str:
    """The calibration error on fresh seeds, the cameras as calibrated against re-calibrated
    from the arm, paired episode by episode (``failed`` seeds: the others succeeded)."""
    from scorbot_gym.evaluation.summary import newcombe_paired_diff

    runs = {
        "as calibrated (`--calibration none`)": FRESH_UNCALIBRATED,
        "re-calibrated from the arm (`--calibration arm`)": FRESH_CALIBRATED,
    }
    runs = {label: read("closed_loop.json", config) for label, config in runs.items()}
    first = next(iter(runs.values()))
    seeds = [str(first["seed"] + i) for i in range(first["episodes_per_arm"])]
    arms = {k: next(iter(d["arms"].values())) for k, d in runs.items()}
    ok = {k: [s not in a["failed"] for s in seeds] for k, a in arms.items()}
    ref = list(arms)[0]
    rows = []
    for label, a in arms.items():
        vs = "(reference)"
        if label != ref:
            diff = newcombe_paired_diff(ok[label], ok[ref])
            lo, hi = diff["ci95"]
            vs = (f"{100 * diff['diff']:+.1f} ({100 * lo:+.1f} to {100 * hi:+.1f}), "
                  f"{diff['only_a']} vs {diff['only_b']}, p = {diff['mcnemar_p']:.1g}")  # fmt: skip
        rows.append([label, f"{pct(a['success_rate'])} {ci(a['success_rate_ci95'])}",
                     failures(a["failure_causes"]), vs])  # fmt: skip
    head = ["cameras", "success (95 % CI)", "failures",
            "Δ, points (95 % CI), discordant, McNemar p"]  # fmt: skip
    return f"`{first['perturbations'][0]}`, seeds {seeds[0]}–{seeds[-1]}:\n\n" + table(head, rows)


def policy_name(policy: str) -> str:
    """A policy as the comparison names it: ``scripted``, ``rl``, or its run's folder."""
    parts = Path(policy).parts
    return "/".join(parts[-3:]) if len(parts) > 1 else policy


#: compare.json's held-out-object configs (issue 49 item 5): the shipped arms on objects outside
#: the catalogue (``benchmarks/compare.py --objects heldout:GROUP``), one column each
NEW_OBJECT_CONFIGS = {
    "new_objects_heading": "heading matters (5 objects)",
    "new_objects_symmetric": "near-symmetric (5 objects)",
}
#: a residual trained on 8 catalogue objects, on the 3 it never saw and on its own 8
CATALOGUE_SPLIT_CONFIGS = {
    "heldout_objects": "the 3 catalogue objects it trained without",
    "heldout_training_objects": "the 8 it trained on",
}


def _versus_scripted(d: dict, r: dict) -> str:
    diff = next(x for x in d["differences"] if x["a"] == r["policy"])
    return (
        f"{pct(r['success_rate'])} {ci(r['ci95'])}, {100 * diff['diff']:+.1f} pts, "
        f"p = {diff['mcnemar_p']:.2g}"
    )


def compare_heldout_objects() -> str:
    """Each shipped arm on objects outside the catalogue, against ``scripted`` paired by seed
    (one row per arm, one column per group); then the catalogue-split residual as a line."""
    configs = {c: read("compare.json", c) for c in NEW_OBJECT_CONFIGS}
    for d in configs.values():
        assert d["results"][0]["policy"] == "scripted"  # the reference
    arms = [r["policy"] for r in next(iter(configs.values()))["results"]]
    rows = []
    for arm in arms:
        cells = []
        for d in configs.values():
            r = next(x for x in d["results"] if x["policy"] == arm)
            cells.append(f"{pct(r['success_rate'])} {ci(r['ci95'])}" if arm == "scripted"
                         else _versus_scripted(d, r))  # fmt: skip
        rows.append([f"`{policy_name(arm)}`", *cells])
    episodes = {d["episodes"] for d in configs.values()}
    head = ["arm (true pose)"] + [f"{v}, {min(episodes)} episodes: Δ vs `scripted`, McNemar p"
                                  for v in NEW_OBJECT_CONFIGS.values()]  # fmt: skip
    split = []
    for config, objects in CATALOGUE_SPLIT_CONFIGS.items():
        d = read("compare.json", config)
        r = d["results"][1]
        split.append(f"on {objects} {_versus_scripted(d, r)} ({d['episodes']} episodes)")
    name = policy_name(read("compare.json", "heldout_objects")["results"][1]["policy"])
    line = f"A residual trained on 8 catalogue objects (`{name}`): " + "; ".join(split) + "."
    return table(head, rows) + "\n" + line + "\n"


def compare_cartesian_ik() -> str:
    """The closed-form IK against damped least squares, every arm on the same fresh seeds
    (``compare.json`` configs ``ik_dls`` / ``ik_closed_form``), paired episode by episode."""
    from scorbot_gym.evaluation.summary import newcombe_paired_diff

    old, new = read("compare.json", "ik_dls"), read("compare.json", "ik_closed_form")
    assert (old["cartesian_ik"], new["cartesian_ik"]) == ("dls", "closed_form")
    assert old["seeds"] == new["seeds"]
    before = {(r["policy"], r["pose"]): r["episode_success"] for r in old["results"]}
    parts, same, total = [], 0, 0
    for r in new["results"]:
        a, b = before[(r["policy"], r["pose"])], r["episode_success"]
        d = newcombe_paired_diff([x == "1" for x in a], [y == "1" for y in b])
        same += len(a) - d["only_a"] - d["only_b"]
        total += len(a)
        parts.append(
            f"`{policy_name(r['policy'])}` {a.count('1')} → {b.count('1')} "
            f"({d['only_a']} vs {d['only_b']} discordant, McNemar p = {d['mcnemar_p']:.2g})"
        )
    return (
        "Configs without `cartesian_ik` ran before 2026-11-28 with damped-least-squares IK "
        "(`--cartesian-ik dls`). The closed form against it (configs `ik_dls`, "
        f'`ik_closed_form`: `--seed {old["seeds"][0]} --noise ""`), {old["episodes"]} paired '
        "episodes per arm, true pose, successes dls → closed form: "
        + ", ".join(parts)
        + f"; {same} of {total} episodes end the same.\n"
    )


#: compare.json's run of the from-scratch arm with the estimator, on the main run's seeds
SCRATCH_MANIFOLD = "manifold_rl_scratch"
#: compare.json's run of the arms with the true pose hidden near the hand (occluded_oracle)
OCCLUDED = "occluded_pose"
#: ... and of the from-scratch arm hidden within one fixed distance each (occluded@D)
OCCLUDED_DISTANCE = "occluded_distance"


def _occluded_distance_sentence() -> str:
    """Success of each arm against the distance within which the object is hidden (config
    ``occluded_distance``); empty without it."""
    try:
        o = read("compare.json", OCCLUDED_DISTANCE)
    except KeyError:
        return ""
    arms: dict[str, list[str]] = {}
    for r in o["results"]:
        low, _, high = r["pose"].partition("@")[2].partition(":")
        where = f"{100 * float(low):g} cm" if low == high else f"{low}–{high} m"
        arms.setdefault(r["label"], []).append(f"{where} {pct(r['success_rate'])}")
    return (
        f"Hidden within one fixed distance of the hand (config `{OCCLUDED_DISTANCE}`, the same "
        "seeds): " + "; ".join(f"`{a}` " + ", ".join(v) for a, v in arms.items()) + ".\n"
    )


def _occluded_sentence() -> str:
    """Each arm of the ``occluded_pose`` config: true pose -> the same pose hidden while the
    hand is near (the training corruptor), paired on the same seeds; empty without it."""
    from scorbot_gym.evaluation.summary import newcombe_paired_diff

    try:
        o = read("compare.json", OCCLUDED)
    except KeyError:
        return ""
    by = {(r["policy"], r["pose"]): r for r in o["results"]}
    parts = []
    for policy in dict.fromkeys(r["policy"] for r in o["results"]):
        a, b = by[(policy, "occluded")], by[(policy, "oracle")]
        ok = [[c == "1" for c in r["episode_success"]] for r in (a, b)]
        diff = newcombe_paired_diff(*ok)
        parts.append(
            f"`{a['label']}` {pct(b['success_rate'])} → {pct(a['success_rate'])} "
            f"({100 * diff['diff']:+.1f} points, McNemar p = {diff['mcnemar_p']:.2g})"
        )
    return (
        f"\nThe true pose hidden while the hand is within 6–20 cm of the object (`occluded`, "
        f"the estimator's one systematic loss without its errors; config `{OCCLUDED}`, "
        f"{o['episodes']} paired episodes from seed {o['seeds'][0]}), true pose → hidden: "
        + "; ".join(parts)
        + ".\n"
    )


def compare_arms() -> str:
    """``compare.json``, one row per arm (``scorbot_gym.evaluation.compare.markdown_table``),
    then the from-scratch arm with the estimator against itself with the true pose, paired
    (#49's targets: >= 80 % with the true pose, within 10 points of it with the estimator)."""
    from scorbot_gym.evaluation.compare import markdown_table
    from scorbot_gym.evaluation.summary import newcombe_paired_diff

    d, m = read("compare.json"), read("compare.json", SCRATCH_MANIFOLD)
    assert d["seeds"] == m["seeds"]
    by = {(r["policy"], r["pose"]): r for r in d["results"] + m["results"]}
    oracle, est = by[("rl_scratch", "oracle")], by[("rl_scratch", "manifold")]
    ok = [[c == "1" for c in r["episode_success"]] for r in (est, oracle)]
    diff = newcombe_paired_diff(*ok)
    blind = by.get(("rl_scratch", "chance"))  # the estimator's rotation swapped for a constant
    chance = (
        f"; with the rotation-blind chance pose (`chance`) {pct(blind['success_rate'])} "
        f"{ci(blind['ci95'])}"
        if blind
        else ""
    )
    estimator = (
        f"\nWith the pose-manifold estimator (no privileged input; config `{SCRATCH_MANIFOLD}`, "
        f"the same seeds): `scripted` {pct(by[('scripted', 'manifold')]['success_rate'])}, "
        f"`rl_scratch` {pct(est['success_rate'])} {ci(est['ci95'])}, "
        f"{100 * diff['diff']:+.1f} points {ci(diff['ci95'])} from itself with the true pose "
        f"(McNemar p = {diff['mcnemar_p']:.2g}){chance}; targets (#49): ≥ 80 % with the true pose "
        f"({'met' if oracle['success_rate'] >= 0.8 else 'not met'}), within 10 points of it "
        f"with the estimator ({'met' if diff['diff'] >= -0.10 else 'not met'}).\n"
    )
    return markdown_table(d) + estimator + _occluded_sentence() + _occluded_distance_sentence()


def _condition_words(cond: dict) -> str:
    """``with the true pose`` / ``with heading noise σ 20°`` / ... for a compare condition."""
    if cond["source"] == "oracle":
        return "with the true pose"
    if cond.get("estimator") == "chance":  # the manifold source, but not its estimator
        return (
            "at the rotation-blind chance level (the same masks and recognised identity, the "
            "position from the image, a constant rotation)"
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
    """success@5° [asymmetric banana] per (protocol, estimator) and occlusion, from the config
    ``{protocol}{suffix}`` of ``pose_ablation.json.gz``; the 95 % CI in the first column. ``cost``
    adds the share of views answered and the median ``predict`` wall time at the first level
    (two workers sharing two cores: not a single-core figure)."""
    names = names or {}

    def render() -> str:
        rows, levels = [], None
        for protocol in protocols:
            d = read(ABLATION, f"{protocol}{suffix}")
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
    names = _select_names(read(ABLATION, "top-resting_select")["spec"]["estimators"])
    return sweep_table("_select", names=names)()


def headline_ablation() -> str:
    d = read(ABLATION, "side-turntable_select")
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
        f"(`benchmarks/results/pose_ablation.json.gz`, config `side-turntable_select`).\n"
    )


def fig3_curves() -> str:
    """Each estimator's curve over 0–95 % as mean success / first level at or below chance
    [mean over the asymmetric banana], from each ``{protocol}_fig3`` config's ``curves``."""
    per = {p: read(ABLATION, f"{p}_fig3") for p in PROTOCOLS}
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
    protocol, from each ``{protocol}_stages`` config's ``stage_ablation`` rows (``[coarse]``:
    refine off)."""
    per = {p: read(ABLATION, f"{p}_stages")["stage_ablation"] for p in PROTOCOLS}
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
    d = read(ABLATION, "side-turntable_perturbations")
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


def _rate(r: dict, key: str = "success_rate", ci_key: str = "success_rate_ci95") -> str:
    return f"{pct(r[key])} {ci(r[ci_key])}"


def clutter_closed_loop() -> str:
    """Per arm of the main run (2 distractors) and of the runs that change one component."""
    rows = []
    runs = [(None, None), ("200_no_table_prior", "no table-top prior")]
    runs += [("largest_blob_200", None), ("random_blob_200", None)]
    for config, note in runs:
        d = read("clutter_closed_loop.json", config)
        for k, arms in d["runs"].items():
            for arm, a in arms.items():
                p = a.get("perception") or {}
                rows.append(
                    [
                        f"`{arm}`" + (f", {note}" if note else ""),
                        f"{a['episodes']} ({k} distractors)",
                        _rate(a),
                        failures(a["failure_causes"]),
                        pct(a.get("wrong_object_rate")),
                        pct(p.get("target_recognition_accuracy")),
                        str(a.get("distractors_knocked_over", "—")),
                    ]
                )
    head = ["pose source", "episodes", "success (95 % CI)", "failures", "wrong object",
            "target recognised", "distractors knocked over"]  # fmt: skip
    return table(head, rows)


def clutter_approach() -> str:
    d = read("clutter_approach.json", "5100")
    rows = [
        [f"`{c}`", str(r["episodes"]), _rate(r), failures(r["failure_causes"])]
        for c, r in d["runs"].items()
    ]
    return (
        f"Seeds {d['seed']}–{d['seed'] + d['episodes'] - 1}, {d['distractors']} distractors, "
        f"`{d['pose_source']}` pose (config `5100`):\n\n"
        + table(["controller", "episodes", "success (95 % CI)", "failures"], rows)
    )


def blob_split() -> str:
    d = read("blob_split.json")
    rows = [
        [
            f"`{name}`",
            pct(s["shared_split_correctly"]),
            f"{s['shared_mean_best_iou']:.3f}",
            pct(s["single_object_over_split"]),
            f"{s['median_ms_per_view']:.2f}",
        ]
        for name, s in d["splitters"].items()
    ]
    s = next(iter(d["splitters"].values()))
    head = [
        "splitter",
        f"shared blobs split correctly (of {s['shared_components']})",
        "mean best IoU",
        f"single-object blobs over-split (of {s['single_object_components']})",
        "median ms / view",
    ]
    return table(head, rows)


def segmentation() -> str:
    d = read("segmentation.json.gz")
    q = d["mask_quality"]
    rows = []
    for cam in ("top", "side", "all"):
        c = q[cam]
        rows.append(
            [
                cam,
                str(c["iou_visible"]["n"]),
                f"{c['iou_visible']['median']:.3f}",
                f"{c['iou_visible_arm_touching']['median']:.3f}",
                f"{c['segment_ms']['median']:.1f}",
            ]
        )
    loop = d["timing"]["loop_cpu_ms"]
    stages = ", ".join(f"{k} {v:.1f}" for k, v in loop.items())
    return (
        table(
            [
                "camera",
                "frames (object visible)",
                "median IoU",
                "median IoU, arm touching",
                "segment ms",
            ],
            rows,
        )  # fmt: skip
        + f"\nLoop CPU ms per step (render + segment + recognise + estimate): {stages}.\n"
    )


def recognition() -> str:
    d = read("recognition.json")
    levels = list(next(iter(d["accuracy"].values())))
    rows = [
        [f"`{name}`"] + [pct(acc[lv]) for lv in levels] + [f"{d['median_ms'][name]:.1f}"]
        for name, acc in d["accuracy"].items()
    ]
    rows.append(["chance (1 / classes)"] + [pct(d["chance"])] * len(levels) + ["—"])
    head = ["recogniser"] + [f"{lv} occluded" for lv in levels] + ["median ms"]
    return table(head, rows)


def shape_recognition() -> str:
    d = read("shape_recognition.json")
    h = d["headline"]
    rows = [
        [f"headline ({len(h['split_seeds'])} random 50/50 splits)"]
        + [f"{pct(m)} ± {100 * h['accuracy_std'][c]:.1f}" for c, m in h["accuracy_mean"].items()]
    ]
    for key in ("with_metric_size", "unseen_viewpoints", "scene_cameras",
                "scene_cameras_scene_trained"):  # fmt: skip
        clf = d[key]["classifiers"]
        rows.append([f"`{key}`"] + [pct(clf[c]["accuracy"]) for c in h["accuracy_mean"]])
    return table(["split"] + [f"`{c}`" for c in h["accuracy_mean"]], rows)


def pose_manifold() -> str:
    d = read("pose_manifold.json")
    rows = [
        [k, f"{d['targets'][k]:g}", f"{d['measured'][k]:g}", "met" if d["met"][k] else "NOT met"]
        for k in d["targets"]
    ]
    w, h = d["setup"]["image"]
    return (
        f"Top camera {w} × {h}, 11 objects, {d['results']['views_per_object']} held-out views "
        f"per object and level:\n\n" + table(["figure", "target", "measured", ""], rows)
    )


def pose_baselines() -> str:
    """success@5° per estimator (rows) and protocol × occlusion (columns), all four objects;
    the asymmetric ones alone in brackets at the first level."""
    d = read("pose_baselines.json")
    protocols = list(d["results"])
    levels = list(next(iter(d["results"][protocols[0]].values()))["levels"])
    rows = []
    for est in d["results"][protocols[0]]:
        row = [f"`{est}`"]
        for proto in protocols:
            lv = d["results"][proto][est]["levels"]
            cells = [pct(lv[k]["all"]["success_5deg"]) for k in levels]
            cells[0] += f" [{pct(lv[levels[0]]['asymmetric']['success_5deg'])}]"
            row.append(" / ".join(cells))
        rows.append(row)
    head = ["estimator"] + [f"`{p}` {' / '.join(f'{k} %' for k in levels)}" for p in protocols]
    return table(head, rows)


def pose_latency() -> str:
    d = read("pose_latency.json")
    names = _select_names(d["estimators"])
    rows = [
        [f"`{r['protocol']}`", short(r["estimator"], names), str(r["n"]), f"{r['median_ms']:.1f}",
         f"{r['p90_ms']:.1f}", f"{r['ratio_to_reference']:.2f}"]
        for r in d["results"]
    ]  # fmt: skip
    head = ["protocol", "estimator", "views", "median ms", "p90 ms", f"÷ `{d['reference']}`"]
    return table(head, rows)


def env_memory() -> str:
    d = read("env_memory.json")
    rows = []
    for name, r in d["results"].items():
        rows.append(
            [
                f"`{name}`",
                f"{r['rss_mb']['after_make']:.0f} / {r['rss_mb']['after_catalogue_pass']:.0f}",
                f"{r['cold_start_s']['first_resets_total']:.2f}",
                f"{r['steady_reset_ms']['median']:.2f} / {r['steady_reset_ms']['p90']:.2f}",
                f"{r['steady_reset_cpu_ms']['median']:.2f}",
            ]
        )
    head = ["configuration", "RSS MB after make / after every object", "first resets (s)",
            "reset ms median / p90", "reset CPU ms"]  # fmt: skip
    return table(head, rows)


#: vector-env configurations of the ablations (``--ablations``), in the JSON, not the table
VECTOR_ABLATIONS = ("async_pinned", "async_cap", "async_raster_thread")


def vector_env() -> str:
    """env steps/s (÷ the plain env) per configuration (rows) and setting (columns)."""
    d = read("vector_env.json")
    settings = list(d["results"])
    configs = list(dict.fromkeys(c for s in settings for c in d["results"][s]))
    configs = [c for c in configs if c.split("-")[0] not in VECTOR_ABLATIONS]
    rows = []
    for config in configs:
        row = [f"`{config}`"]
        for s in settings:
            r = d["results"][s].get(config)
            ok = r is not None and "error" not in r
            row.append(
                f"{r['env_steps_per_second_median']:.0f} ({r['ratio_to_plain']:.2f}×), "
                f"{r['cpu_ms_per_env_step_median']:.2f} ms CPU"
                if ok
                else "—"
            )
        rows.append(row)
    head = ["configuration"] + [f"{s}: env steps/s (÷ plain), CPU per env step" for s in settings]
    return table(head, rows)


def _arms_table(arms: dict, ci_key: str) -> str:
    rows = [[f"`{k}`", str(a["episodes"]), _rate(a, ci_key=ci_key)] for k, a in arms.items()]
    return table(["arm", "episodes", "success (95 % CI)"], rows)


def learned_policy() -> str:
    d = read("learned_policy.json")
    t = d["training"]
    return _arms_table(d["arms"], "success_rate_ci95") + (
        f"\nTraining: {t['demonstration_episodes']} demonstrations + {t['dagger_episodes']} "
        f"DAgger episodes, {t['env_steps']:,} env steps, {t['wall_time_s']:,.0f} s; "
        f"seeds {d['eval_seeds'][0]}–{d['eval_seeds'][1]}.\n"
    )


def _pixel_recipe(config: dict) -> str:
    """The pixel arm's recipe, from its training config (older records lack the newer keys:
    the defaults of their time, one top-camera frame, no stall input, no keep-closing)."""
    cameras = config.get("cameras") or [config.get("camera", "top")]
    stack = config.get("net", {}).get("frame_stack", 1)
    stall = config["history"].get("stall_steps", 0)
    return (
        f"{' + '.join(cameras)}, {stack} frame(s) each, stall input {stall or 'none'}, "
        f"keep-closing labels {'yes' if config.get('expert_keeps_close') else 'no'}, "
        f"random shift ±{config.get('shift', 0)} px, {config['demos']} demonstrations + "
        f"{config['dagger_rounds']}×{config['dagger_episodes']} DAgger"
    )


def pixel_policy() -> str:
    d = read("pixel_policy.json")
    diff = d["paired_differences"]["state_minus_pixel"]
    t = d["pixel_training"]
    differs = d.get("recipe_vs_state", {}).get("differs")
    besides = (
        f" Besides the pose, the arms differ in: {'; '.join(differs) or 'nothing recorded'}."
        if differs is not None
        else " Its differences from that state arm were not recorded (before `recipe_vs_state`)."
    )
    return _arms_table(d["arms"], "ci95") + (
        f"\nState − pixel: {100 * diff['diff']:+.1f} points "
        f"{ci(diff['ci95'])}, McNemar p = {diff['mcnemar_p']:.2g}. Pixel recipe: "
        f"{_pixel_recipe(t['config'])}; {t['env_steps']:,} env steps, "
        f"{t['wall_time_s']:,.0f} s on {d['machine'].get('cuda', 'CPU')}.{besides}\n"
    )


def finetune() -> str:
    """The fine-tuned policies against the imitation policy, per pose condition."""
    d = read("finetune.json")
    rows = []
    for x in d["finetuned_vs_imitation"]:
        rows.append(
            [
                f"`{x['pose']}`",
                f"`{x['a']}` − `{x['b']}`",
                f"{100 * x['diff']:+.1f} pts {ci(x['ci95'])}",
                f"{x['mcnemar_p']:.2g}",
            ]
        )
    return table(["pose", "arms", "paired difference (95 % CI)", "McNemar p"], rows)


#: learning_curves.json's variants shown beside the main run (#49's from-scratch recipes): the
#: main run of 2026-11-27 ('default' SAC to 30k, the residual); training under the true pose
#: hidden near the hand (from scratch, and from rl_scratch's weights)
CURVE_CONFIGS = ("first_runs", "occluded_pose")


def _stall(arm: dict) -> str:
    """Where the last evaluation's failed episodes ended, median cm, per seed ("–": not
    recorded by runs from before the diagnostic)."""
    seen = [d["final"] for d in arm.get("final_failed_grasp_distance_m", [])]
    if not seen or all(v is None for v in seen):
        return "–"
    return " / ".join("–" if v is None else f"{100 * v:.0f}" for v in seen)


def _peaks(arm: dict) -> str:
    """Each seed's best evaluation, and the env steps of its first >= 50 % and >= 80 % ("–":
    not reached, or a report from before peaks were recorded)."""
    peaks = arm.get("peak")
    if not peaks:
        return "–"
    reached = arm["first_reached"]

    def steps(level: str, i: int) -> str:
        t = reached[level]["timesteps"][i]
        return "–" if t is None else f"{t // 1000}k"

    return "; ".join(
        f"{100 * p['success_rate']:.0f} % at {p['timesteps'] // 1000}k "
        f"({steps('0.5', i)} / {steps('0.8', i)})"
        for i, p in enumerate(peaks)
    )


def _seed_ends(arm: dict) -> str:
    """Each seed's last evaluation where the seeds stopped at different steps (the mean
    stops at the shortest)."""
    ends = [run["timesteps"][-1] for run in arm.get("per_seed", [])]
    return f" (seeds: {' / '.join(f'{t // 1000}k' for t in ends)})" if len(set(ends)) > 1 else ""


def learning_curves() -> str:
    d = read("learning_curves.json")
    arms = dict(d["arms"].items())
    for config in CURVE_CONFIGS:
        for name, a in read("learning_curves.json", config)["arms"].items():
            arms[f"{name} (config `{config}`)"] = a
    rows = []
    for name, a in arms.items():
        b = a["by_timesteps"]
        band = (
            f" ({100 * b['ci95_low'][-1]:.0f}–{100 * b['ci95_high'][-1]:.0f})"
            if b.get("ci95_low")
            else ""
        )
        rows.append(
            [
                name,
                str(len(a["seeds"])),
                f"{int(b['timesteps'][-1]):,}" + _seed_ends(a),
                f"{100 * b['mean'][-1]:.0f} %{band}",
                f"{a['by_wall_s']['wall_s'][-1]:,.0f} s",
                _peaks(a),
                _stall(a),
            ]
        )
    head = ["arm", "seeds", "env steps", "success there, mean (95 % CI)", "wall time",
            "best evaluation per seed (first ≥ 50 % / ≥ 80 %)",
            "failed episodes end (cm from the grasp point)"]  # fmt: skip
    learned = read("compare.json")["arms"]["learned"]["training"]
    oracle = next(r for r in read("compare.json")["results"]
                  if r["policy"] == "learned" and r["pose"] == "oracle")  # fmt: skip
    return table(head, rows) + (
        f"\nFor scale, imitation (`learned`): {learned['demonstration_episodes']} scripted "
        f"demonstrations plus DAgger, {learned['env_steps']:,} env steps and "
        f"{learned['wall_time_s']:,.0f} s of training, {pct(oracle['success_rate'])} on the 200 "
        "test seeds with the true pose (`compare.json`).\n"
    )


def table_support() -> str:
    d = read("table_support.json")
    rows = []
    for tilt, r in d["tilts"].items():
        q = r["tilt_deg_quantiles"]
        rows.append(
            [
                f"{tilt}°",
                str(r["estimates"]),
                f"{q['p50']:.2f} / {q['p90']:.2f}",
                " / ".join(f"{100 * v:.0f}" for v in r["share_under_deg"].values()),
                f"{r['median_abs_height_error_mm']:.2f}",
            ]
        )
    under = "/".join(f"{k}" for k in next(iter(d["tilts"].values()))["share_under_deg"])
    head = ["true tilt", "estimates", "estimated tilt p50 / p90 (°)",
            f"share under {under}° (%)", "median height error (mm)"]  # fmt: skip
    return table(head, rows)


def tilted_in_loop(section: str = "loop") -> str:
    d = read("tilted_in_loop.json")[section]
    rows = [
        [
            f"`{name}`",
            str(r["episodes"]),
            f"{pct(r['grasp_success'])} {ci(r['grasp_success_ci95'])}",
            str(r["estimates_valid"]),
            pct(r["success_5deg_of_valid_estimates"]),
        ]
        for name, r in d["totals"].items()
    ]
    head = ["arm", "episodes", "grasp success (95 % CI)", "valid estimates",
            "success@5° of valid estimates"]  # fmt: skip
    return table(head, rows)


def cli_startup() -> str:
    d = read("cli_startup.json")
    rows = [
        [
            f"`scorbot-gym {c['argv']}`",
            f"{c['median_s']:.2f}",
            f"{c['baseline']['median_s']:.2f}" if c.get("baseline") else "—",
            ", ".join(c["heavy_imports"]) or "none",
        ]
        for c in d["commands"]
        if c["argv"] == "--help" or not c["argv"].endswith("--help")
    ]
    head = ["command", "median s", "before (same run)", "heavy imports"]
    return (
        f"{d['runs']} fresh processes per command (each sub-command's `--help` is in the "
        "JSON):\n\n" + table(head, rows)
    )


def wrapper_step() -> str:
    """Bare and oracle-wrapped step, without images and with the top camera's image, and the
    wrapped-over-bare ratio of CPU time per step (median and range over the paired runs)."""
    d = read("wrapper_step.json")
    rows, ratios = [], []
    for setting, label in (("no_images", "no images"), ("camera_320x240", "320 × 240 RGB")):
        for name, r in d["step"].get(setting, {}).items():
            if "steps_per_cpu_second_median" not in r:
                continue
            cpu = r["steps_per_cpu_second_runs"]
            rows.append([label, f"`{name}`",
                         f"{r['steps_per_cpu_second_median']:.0f} ({min(cpu):.0f}–{max(cpu):.0f})",
                         f"{r['steps_per_second_median']:.0f}"])  # fmt: skip
        ratio = d["step"].get(setting, {}).get("wrapped_over_bare")
        if ratio:
            ratios.append(
                f"{label} {ratio['cpu_time_ratio_median']:.2f}× "
                f"({ratio['cpu_time_ratio_min']:.2f}–{ratio['cpu_time_ratio_max']:.2f}, "
                f"{ratio['pairs']} pairs)"
            )
    text = table(["setting", "env", "steps / CPU s (range)", "steps/s (wall)"], rows)
    if ratios:
        text += f"\nWrapped ÷ bare CPU time per step: {'; '.join(ratios)}.\n"
    return text


#: the keys a result's conditions line quotes where its run has them, with their wording
CONDITION_KEYS = (
    ("episodes", "{} episodes"),
    ("episodes_per_arm", "{} episodes per arm"),
    ("episodes_per_tilt", "{} episodes per tilt"),
    ("seed", "seed {}"),
    ("eval_seeds", "seeds {0[0]}–{0[1]}"),
    ("repeats", "{} repetitions"),
    ("resets", "{} resets"),
    ("runs", "{} runs"),
)


def conditions(name: str) -> Callable[[], str]:
    """One line under a benchmark's heading: where its main run's figures come from (episodes,
    seeds, machine, date), read from the file, and the configs it holds beside it."""

    def render() -> str:
        from pose.fileio import result_configs

        d = read(name)
        parts = []
        for key, words in CONDITION_KEYS:
            value = d.get(key)
            if isinstance(value, (int, str)) or (key == "eval_seeds" and value):
                parts.append(words.format(value))
        machine = d.get("machine") or d.get("environment") or {}
        if isinstance(machine, dict):
            cpus = machine.get("cpus") or machine.get("cpu_count") or machine.get("usable_cores")
            parts += [f"{cpus} CPUs"] if cpus else []
            parts += [machine["cuda"]] if machine.get("cuda") else []
        if d.get("date_utc"):
            parts.append(d["date_utc"][:10])
        configs = result_configs(RESULTS / name)
        line = f"Main run: {', '.join(parts) or 'see the file'} (`results/{name}`)"
        if configs:
            line += f"; variants beside it: {', '.join(f'`{c}`' for c in configs)}"
        return line + ".\n"

    return render


#: every result file: its script, its figure and the names of its configs
def results_index() -> str:
    from pose.fileio import result_configs

    rows = []
    for path in sorted(RESULTS.iterdir()):
        if path.suffix == ".png" or path.name.startswith("."):
            continue
        stem = path.name.removesuffix(".gz").removesuffix(".json")
        png = RESULTS / f"{stem}.png"
        configs = result_configs(path)
        rows.append(
            [
                f"`{stem}.py`",
                f"[`{path.name}`](results/{path.name})",
                f"[`{png.name}`](results/{png.name})" if png.is_file() else "—",
                ", ".join(f"`{c}`" for c in configs) or "—" if len(configs) <= 8
                else f"{len(configs)} (`{configs[0]}` … `{configs[-1]}`)",
            ]
        )  # fmt: skip
    return table(["script", "result", "figure", "configs (variants)"], rows)


TABLES: dict[str, Callable[[], str]] = {
    "headline-closed-loop": headline_closed_loop,
    "headline-compare": headline_compare,
    "headline-ablation": headline_ablation,
    "closed-loop": closed_loop_arms,
    "closed-loop-robustness": closed_loop_robustness,
    "closed-loop-perturbations": closed_loop_perturbations,
    "compare": compare_arms,
    "compare-heldout-objects": compare_heldout_objects,
    "compare-cartesian-ik": compare_cartesian_ik,
    "rl-training": rl_training,
    "env-step": env_step,
    "env-step-ratios": env_step_ratios,
    "fig3-curves": fig3_curves,
    "select": select_table,
    "stages": stage_ablation,
    "view-perturbations": view_perturbations,
    "results-index": results_index,
    **{
        f"conditions-{p.name.removesuffix('.gz').removesuffix('.json')}": conditions(p.name)
        for p in sorted(RESULTS.glob("*.json*"))
        if p.name != "pose_ablation.json.gz"  # no main run: each sweep is a config
    },
    "clutter-closed-loop": clutter_closed_loop,
    "clutter-approach": clutter_approach,
    "blob-split": blob_split,
    "segmentation": segmentation,
    "recognition": recognition,
    "shape-recognition": shape_recognition,
    "pose-manifold": pose_manifold,
    "pose-baselines": pose_baselines,
    "pose-latency": pose_latency,
    "env-memory": env_memory,
    "vector-env": vector_env,
    "learned-policy": learned_policy,
    "pixel-policy": pixel_policy,
    "finetune": finetune,
    "learning-curves": learning_curves,
    "table-support": table_support,
    "tilted-in-loop": tilted_in_loop,
    "tilted-in-loop-recognize": lambda: tilted_in_loop("loop_recognize"),
    "closed-loop-paired": closed_loop_paired,
    "closed-loop-calibration-fresh": closed_loop_calibration_fresh,
    "cli-startup": cli_startup,
    "wrapper-step": wrapper_step,
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
