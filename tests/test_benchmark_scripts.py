"""The benchmark scripts stay runnable: the figures in benchmarks/README.md come from them.

Nothing here runs a benchmark (that takes minutes to hours); it checks what breaks silently
when the package changes under a script: every script imports and parses ``--help``, bad
arguments give a one-line usage error before any work starts, and the scripts that redraw their
PNG from a committed JSON still can. Each script runs in its own interpreter, as a user runs it:
the scripts set thread-count variables at import, which must not leak into the test process.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from pose.fileio import atomic_write_json, read_json, read_result
from scorbot_gym.data.protocols import protocol_names

ROOT = Path(__file__).resolve().parents[1]
BENCHMARKS = ROOT / "benchmarks"
RESULTS = BENCHMARKS / "results"
ABLATION = RESULTS / "pose_ablation.json.gz"
SCRIPTS = sorted(p.relative_to(BENCHMARKS).as_posix() for p in BENCHMARKS.rglob("*.py"))

HELP_ALL = """
import json, runpy, sys
out = {}
for path in sys.argv[1:]:
    try:
        main = runpy.run_path(path, run_name="benchmark_under_test")["main"]
        main(["--help"])
        out[path] = "returned without exiting"
    except SystemExit as exc:
        out[path] = exc.code
    except BaseException as exc:
        out[path] = f"{type(exc).__name__}: {exc}"
print(json.dumps(out))
"""


def _run(*args: str, timeout: float = 180) -> subprocess.CompletedProcess:
    """Run a script; a short timeout, so that arguments wrongly accepted fail fast instead of
    running a whole benchmark."""
    env = {**os.environ, "MUJOCO_GL": "egl", "PYTHONPATH": str(ROOT)}
    return subprocess.run(
        [sys.executable, *args], cwd=ROOT, env=env, capture_output=True, text=True,
        timeout=timeout,
    )  # fmt: skip


def _usage_error(proc: subprocess.CompletedProcess) -> str:
    """argparse's error line (exit status 2, last line of stderr, no traceback)."""
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr, proc.stderr[-2000:]
    return proc.stderr.strip().splitlines()[-1]


@pytest.mark.slow
def test_every_benchmark_script_imports_and_parses_help():
    assert len(SCRIPTS) >= 15, SCRIPTS  # the glob found the scripts
    proc = _run("-c", HELP_ALL, *(str(BENCHMARKS / s) for s in SCRIPTS))
    assert proc.returncode == 0, proc.stderr[-3000:]
    codes = json.loads(proc.stdout.strip().splitlines()[-1])
    failed = {Path(p).relative_to(BENCHMARKS).as_posix(): c for p, c in codes.items() if c != 0}
    assert not failed, failed


@pytest.mark.parametrize(
    ("script", "args", "message"),
    [
        ("pose_ablation.py", ["--protocols", "top-resting,upside-down"], "unknown protocol"),
        pytest.param(
            "pose_ablation.py", ["--occlusion", "0:100:5"], "occlusion", marks=pytest.mark.slow
        ),
        pytest.param(
            "pose_ablation.py",
            ["--estimators", "chance,no-such-estimator"],
            "unknown estimator",
            marks=pytest.mark.slow,
        ),
        pytest.param(
            "pose_ablation.py", ["--perturbations", "none;glare=2"], "glare", marks=pytest.mark.slow
        ),
        ("closed_loop.py", ["--perturbations", "none;glare=2"], "glare"),
        pytest.param(
            "closed_loop.py",
            ["--perturbations", "none", "--arms", "oracle"],
            "--arms does not",
            marks=pytest.mark.slow,
        ),
        pytest.param(
            "closed_loop.py",
            ["--arms", "oracle;robustnes"],
            "unknown arms ['robustnes']",
            marks=pytest.mark.slow,
        ),
        pytest.param(
            "closed_loop.py", ["--jobs", "0"], "--jobs must be >= 1", marks=pytest.mark.slow
        ),
        pytest.param(
            "closed_loop.py",
            ["--merge", "no-such-part.json"],
            "no-such-part.json",
            marks=pytest.mark.slow,
        ),
        pytest.param(
            "pose_ablation.py",
            ["--estimators", "chance", "--paired", "pca-rbf"],
            "not among",
            marks=pytest.mark.slow,
        ),
        pytest.param(
            "pose_ablation.py",
            ["--protocols", "clutter", "--occlusion", "0,25"],
            "bin edges",
            marks=pytest.mark.slow,
        ),
        ("clutter_closed_loop.py", ["--episodes", "0"], "--episodes"),
        pytest.param(
            "clutter_closed_loop.py",
            ["--regrasps", "-1"],
            "--regrasps must be >= 0",
            marks=pytest.mark.slow,
        ),
        pytest.param(
            "clutter_closed_loop.py",
            ["--support", "floor"],
            "invalid choice: 'floor'",
            marks=pytest.mark.slow,
        ),
        ("table_support.py", ["--tilts", "0", "60"], "--tilts in [0, 45] degrees"),
        ("compare.py", ["--objects", "heldout:round"], "unknown held-out group 'round'"),
        ("compare.py", ["--objects", "box,teapot"], "unknown objects ['teapot']"),
        pytest.param(
            "pose_ablation.py", ["--paired", "pca-rbf("], "pca-rbf(", marks=pytest.mark.slow
        ),
        (
            "pose_ablation.py",
            [
                "--estimators",
                "chance",
                "--paired",
                "chance",
                "--perturbations",
                "none;lighting=0.5",
            ],
            "not with --perturbations",
        ),
    ],
)
def test_bad_arguments_are_one_line_usage_errors(script, args, message, tmp_path):
    out = {  # were an argument wrongly accepted, nothing would be written into results/
        "pose_ablation.py": ["--out", str(tmp_path / "p.json.gz")],
        "closed_loop.py": ["--out", str(tmp_path / "c.json")],
        "clutter_closed_loop.py": ["--out", str(tmp_path / "c.json")],
        "table_support.py": ["--out", str(tmp_path / "t.json")],
        "compare.py": ["--out", str(tmp_path / "c.json")],
    }[script]
    line = _usage_error(_run(str(BENCHMARKS / script), *args, *out))
    assert "error:" in line, line
    assert message in line, line


@pytest.mark.slow
def test_pose_ablation_redraws_its_png_and_rejects_a_foreign_json(tmp_path):
    results = tmp_path / "pose_ablation.json.gz"  # the result file: its figure config
    shutil.copy(ABLATION, results)
    proc = _run(str(BENCHMARKS / "pose_ablation.py"), "--replot", str(results))
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert (tmp_path / "pose_ablation.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert read_json(results) == read_json(ABLATION)  # drawing changes nothing in the file

    sweep = tmp_path / "one_sweep.json.gz"  # a single sweep's record: itself
    atomic_write_json(sweep, read_result(ABLATION, "side-turntable_select"))
    proc = _run(str(BENCHMARKS / "pose_ablation.py"), "--replot", str(sweep))
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert (tmp_path / "one_sweep.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    foreign = tmp_path / "keep_margin_seed1.json"  # a JSON, but not a sweep's
    atomic_write_json(foreign, read_result(ABLATION, "keep_margin_seed1"))
    line = _usage_error(_run(str(BENCHMARKS / "pose_ablation.py"), "--replot", str(foreign)))
    assert str(foreign) in line and not foreign.with_suffix(".png").exists(), line
    truncated = tmp_path / "truncated.json.gz"  # a compressed record cut short
    truncated.write_bytes(sweep.read_bytes()[:999])
    line = _usage_error(_run(str(BENCHMARKS / "pose_ablation.py"), "--replot", str(truncated)))
    assert "not a readable sweep JSON" in line, line


@pytest.mark.slow
def test_pose_ablation_pairs_the_selection_with_each_estimator_from_a_committed_json(tmp_path):
    sweep = tmp_path / "pose_ablation.json.gz"
    data = read_json(ABLATION)
    report = data["configs"]["side-turntable_select"]
    report.pop("paired", None)
    atomic_write_json(sweep, data)
    select = next(e for e in report["spec"]["estimators"] if e.startswith("select("))
    proc = _run(str(BENCHMARKS / "pose_ablation.py"), "--replot", str(sweep), "--paired", select)
    assert proc.returncode == 0, proc.stderr[-2000:]
    paired = read_result(sweep, "side-turntable_select")["paired"]
    assert read_result(sweep, "top-resting_select") == read_result(ABLATION, "top-resting_select")
    others = set(report["spec"]["estimators"]) - {select}
    assert {(r["versus"], r["occlusion"]) for r in paired} == {
        (e, o) for e in others for o in report["spec"]["occlusions"]
    }
    success = {(r["estimator"], r["occlusion"]): r["success_5deg"] for r in report["results"]}
    for r in paired:  # the paired difference is the difference of the two cells' figures
        gap = success[(select, r["occlusion"])] - success[(r["versus"], r["occlusion"])]
        assert r["diff"] == pytest.approx(gap, abs=2e-4)
        assert r["only_estimator"] - r["only_versus"] == round(gap * r["n"])
    old = tmp_path / "side-turntable_all.json.gz"  # written before view_errors
    atomic_write_json(old, read_result(ABLATION, "side-turntable_all"))
    line = _usage_error(_run(str(BENCHMARKS / "pose_ablation.py"), "--replot", str(old),
                             "--paired", "chance"))  # fmt: skip
    assert "has no view_errors" in line, line
    # benchmarks/README.md's reading of the one cell a baseline wins: 1 view against 2, no evidence
    (cell,) = [r for r in paired if r["versus"] == "sift-pnp(upscale=2)" and r["occlusion"] == 0]
    assert (cell["only_estimator"], cell["only_versus"], cell["mcnemar_p"]) == (1, 2, 1.0)


#: the protocols with a committed 0-95 % Fig. 3 and stage sweep; ``clutter`` (bins of measured
#: occlusion, not 5 % steps) has its own sweep, the config clutter_small
SWEPT = tuple(p for p in protocol_names() if p != "clutter")
FIG3 = [f"{protocol}_fig3" for protocol in SWEPT] + [
    f"{protocol}_fig3_fallback"
    for protocol in ("side-turntable", "sparse-headings", "overview", "tilted")
]


@pytest.mark.parametrize("protocol", SWEPT)
def test_the_committed_stage_ablations_follow_from_their_cells(protocol):
    """The stage table of benchmarks/README.md is read from ``stage_ablation``: it must be what
    the file's own cells give, over 0-95 %, for the whole catalogue of variants."""
    from scorbot_gym.experiments.aggregate import stage_ablation

    report = read_result(ABLATION, f"{protocol}_stages")
    assert len(report["spec"]["occlusions"]) == 20
    assert set(report["spec"]["estimators"]) == {
        "manifold", "manifold-no-bunches", "manifold-no-shape", "manifold-no-words",
        "manifold-no-anchor", "manifold-knn", "manifold-scipy", "manifold-silhouette-reference",
    }  # fmt: skip
    assert report["stage_ablation"] == stage_ablation(report["results"])
    assert all("success_5deg_asymmetric" in row for row in report["stage_ablation"])


@pytest.mark.parametrize("name", FIG3)
def test_the_committed_fig3_curves_and_paired_rows_follow_from_their_cells(name):
    """The Fig. 3 summary of benchmarks/README.md is read from ``curves`` and ``paired``: both
    must be what the file's own cells and view errors give."""
    from scorbot_gym.experiments.aggregate import curve_summary, paired_differences

    report = read_result(ABLATION, name)
    assert len(report["spec"]["occlusions"]) == 20  # 0-95 % in 5 % steps, as in the seed
    assert report["curves"] == curve_summary(report["results"], report["chance"])
    selection = report["paired"][0]["estimator"]
    assert selection.startswith(("select(", "fallback(estimator='select("))
    assert report["paired"] == paired_differences(report["view_errors"], selection)
    if selection.startswith("fallback("):  # it answers for the selection only where it has none
        against = [r for r in report["paired"] if r["versus"].startswith("select(")]
        assert len(against) == 20 and all(r["only_versus"] == 0 for r in against)
    cell = {(r["estimator"], r["occlusion"]): r["success_5deg"] for r in report["results"]}
    for row in report["paired"]:
        occ = row["occlusion"]
        assert row["diff"] == pytest.approx(
            cell[(selection, occ)] - cell[(row["versus"], occ)], abs=2e-4
        )


def test_the_committed_perturbation_sweep_is_the_fig3_sweep_when_unperturbed():
    """The perturbation table's first row is read as the unperturbed baseline of every other
    row: its cells must be the Fig. 3 file's (same protocol, models, views and estimators)."""
    report = read_result(ABLATION, "side-turntable_perturbations")
    fig3 = read_result(ABLATION, "side-turntable_fig3")
    assert report["perturbations"][0] == "none" and len(report["perturbations"]) == 5
    keys = ("n", "success_5deg", "success_5deg_asymmetric", "median_rot_err_deg", "valid_rate")
    cells = {(r["estimator"], r["occlusion"]): r for r in fig3["results"]}
    unperturbed = [r for r in report["results"] if r["perturbation"] == "none"]
    assert len(unperturbed) == 2 * len(report["spec"]["estimators"]) == 6
    for r in unperturbed:
        assert {k: r[k] for k in keys} == {
            k: cells[(r["estimator"], r["occlusion"])][k] for k in keys
        }
    assert all(s["fit_errors"] == 0 for s in report["stats"].values())


@pytest.mark.slow
def test_closed_loop_merges_the_parts_of_a_split_run_into_the_whole_runs_report(tmp_path):
    """A batch split by ``--arms`` over several commands joins into the report one run writes:
    the committed report cut in two parts and merged gives back its arms and curves."""
    whole = read_result(RESULTS / "closed_loop.json", "resting_models")  # all arms
    labels = list(whole["arms"])
    first = {**whole, "arms": {k: whole["arms"][k] for k in labels[1::2]}}
    second = {**whole, "arms": {k: whole["arms"][k] for k in labels[::2]}}
    second["robustness"] = {"yaw": [], "pos": []}
    del second["loop_timing_320x240_one_thread"]
    parts = [tmp_path / "a.json", tmp_path / "b.json"]
    for path, part in zip(parts, (first, second), strict=True):
        atomic_write_json(path, part)
    out = tmp_path / "closed_loop.json"
    script = str(BENCHMARKS / "closed_loop.py")
    proc = _run(script, "--merge", *map(str, parts), "--out", str(out))
    assert proc.returncode == 0, proc.stderr[-2000:]
    merged = json.loads(out.read_text())
    assert list(merged["arms"]) == labels  # in the run's order, not the parts'
    for key in ("arms", "robustness", "loop_timing_320x240_one_thread", "seed"):
        assert merged[key] == whole[key]
    assert out.with_suffix(".png").read_bytes()[:4] == b"\x89PNG"
    again = ("--merge", *map(str, parts), "--out", str(out), "--config", "again")
    line = _usage_error(_run(script, *again))  # an existing result file: only with --overwrite
    assert "exists; add --overwrite" in line, line
    proc = _run(script, *again, "--overwrite")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert read_result(out, "again")["arms"] == merged["arms"]  # a named variant beside it
    assert read_result(out) == merged  # the main run untouched
    line = _usage_error(_run(script, "--merge", str(parts[0]), str(parts[0]), "--out", str(out)))
    assert "arms in more than one part" in line, line


@pytest.mark.parametrize(
    ("perturbations", "closed_loop"),
    [
        ("perturbations", None),  # the default models
        ("perturbations_resting_models", "resting_models"),
    ],
)
def test_the_committed_closed_loop_perturbations_start_from_the_main_runs_arm(
    perturbations, closed_loop
):
    """The in-loop perturbation table reads every row against its unperturbed one: that row
    must be the ``manifold`` arm of the closed-loop run with the same models, episode for
    episode."""
    report = read_result(RESULTS / "closed_loop.json", perturbations)
    main_run = read_result(RESULTS / "closed_loop.json", closed_loop)
    assert report["perturbations"][0] == "none" and report["seed"] == main_run["seed"]
    keys = ("episodes", "successes", "failure_causes", "per_object")
    unperturbed, manifold = report["arms"]["none"], main_run["arms"]["manifold"]
    assert {k: unperturbed[k] for k in keys} == {k: manifold[k] for k in keys}
    for label in report["perturbations"][1:]:
        assert report["arms"][label]["config"]["perturbation"] == label


def test_every_result_file_is_named_after_the_script_that_writes_it():
    """One JSON (and at most one figure) per script: variants are configs inside it, so the
    folder answers "what did each script measure" at a glance (issue 51)."""
    files = sorted(p.name for p in RESULTS.iterdir() if not p.name.startswith("."))
    scripts = {Path(s).stem for s in SCRIPTS if "/" not in s}
    stems = [f.removesuffix(".gz").removesuffix(".json").removesuffix(".png") for f in files]
    assert set(stems) <= scripts, set(stems) - scripts
    assert len(stems) == len(files) and all(stems.count(s) <= 2 for s in stems), files
    assert len(files) <= 80
    assert sum((RESULTS / f).stat().st_size for f in files) <= 10 * 2**20


def test_a_result_file_keeps_its_other_runs_when_one_is_written(tmp_path):
    from pose.fileio import result_configs, write_result

    path = tmp_path / "bench.json.gz"
    write_result(path, {"arms": 1})
    write_result(path, {"arms": 2}, "seed1")
    write_result(path, {"arms": 3})  # the main run again: the variant stays
    assert read_result(path) == {"arms": 3} and read_result(path, "seed1") == {"arms": 2}
    assert result_configs(path) == ["seed1"]
    with pytest.raises(KeyError, match="no config 'seed2'; its configs: seed1"):
        read_result(path, "seed2")
    with pytest.raises(ValueError, match="may not carry its own 'configs'"):
        write_result(path, {"configs": {}})


def test_every_closed_loop_arm_is_a_valid_configuration_and_the_defaults_have_theirs():
    """``closed_loop.py`` builds each arm's RolloutConfig (no episodes run): every one is valid,
    the committed arms keep the components they were measured with, and the arm of the
    rollout defaults is the one the README's headline quotes."""
    import argparse
    import runpy

    from scorbot_gym.evaluation.rollout import RolloutConfig

    bench = runpy.run_path(str(BENCHMARKS / "closed_loop.py"), run_name="closed_loop_under_test")
    args = argparse.Namespace(
        episodes=2, seed=1, push_episodes=2, curve_episodes=1, eye_in_hand_episodes=2,
        segmenter="background", no_recognize=False,
    )  # fmt: skip
    arms = bench["_arm_configs"](args)
    default = RolloutConfig(pose="manifold", recognize=True)
    held = arms[bench["TABLE_MEMORY_APPEARANCE_ARM"]]
    assert (held.support, held.recognizer) == (default.support, default.recognizer)
    assert (arms["manifold"].support, arms["manifold"].recognizer) == ("table", "flr+appearance")
    assert arms["manifold, FLR recognition"].recognizer == "flr"
    assert arms["manifold, no table prior"].support == "none"
