"""The comparison figure (:mod:`scorbot_gym.evaluation.compare_plot`): a forest plot of the
paired differences, success on an axis that shows them, per object, one axis per noise kind;
drawn from a report alone (older reports too)."""

import json
from pathlib import Path

import numpy as np
import pytest
from matplotlib.image import imread

from scorbot_gym.evaluation import compare_plot as cp
from scorbot_gym.evaluation.summary import newcombe_paired_diff, wilson_interval

RESULTS = Path(__file__).resolve().parent.parent / "benchmarks" / "results"


def _record(policy: str, pose: str, outcomes: str, noise=None, objects=("box", "banana")):
    k, n = outcomes.count("1"), len(outcomes)
    per_object = {}
    for i, o in enumerate(objects):  # episodes alternate between the objects
        mine = outcomes[i :: len(objects)]
        per_object[o] = {"episodes": len(mine), "successes": mine.count("1")}
    return {
        "policy": policy, "label": policy, "pose": pose, "episodes": n, "successes": k,
        "success_rate": k / n, "ci95": list(wilson_interval(k, n)),
        "noise_pos_m": noise[0] if noise else None, "noise_yaw_deg": noise[1] if noise else None,
        "per_object": per_object, "training": {"trained_from": "scripted"},
        "episode_success": outcomes,
    }  # fmt: skip


def _report(results, **kw):
    return {"episodes": len(results[0]["episode_success"]), "seeds": [0, 9],
            "reference": "scripted", "results": results, **kw}  # fmt: skip


@pytest.fixture()
def small_report():
    """Two policies under the true pose, heading-only and position-only noise, 10 episodes."""
    conds = {"oracle": (0.0, 0.0), "noisy@0:20": (0.0, 20.0), "noisy@0.02:0": (0.02, 0.0)}
    outcomes = {
        ("scripted", "oracle"): "1111111111", ("learned", "oracle"): "1111111110",
        ("scripted", "noisy@0:20"): "1111111110", ("learned", "noisy@0:20"): "1111111100",
        ("scripted", "noisy@0.02:0"): "1110101100", ("learned", "noisy@0.02:0"): "1111111101",
    }  # fmt: skip
    results = [_record(p, c, outcomes[(p, c)], n) for c, n in conds.items()
               for p in ("scripted", "learned")]  # fmt: skip
    return _report(results)


def test_the_figure_draws_every_panel_and_writes_a_png(small_report, tmp_path):
    panels = cp.plot_comparison(small_report, tmp_path / "c.png")
    assert panels == ["success", "differences", "objects", "noise_position", "noise_heading"]
    assert (tmp_path / "c.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    h, w = imread(tmp_path / "c.png").shape[:2]
    assert w > 1000 and h > 600  # printable, not a thumbnail


def test_missing_differences_are_recomputed_from_the_paired_episodes(small_report):
    diffs = cp._differences(small_report, "scripted")
    assert set(diffs) == {("learned", "oracle"), ("learned", "noisy@0:20"),
                          ("learned", "noisy@0.02:0")}  # fmt: skip
    expected = newcombe_paired_diff(
        [c == "1" for c in "1111111101"], [c == "1" for c in "1110101100"]
    )
    assert diffs[("learned", "noisy@0.02:0")] == expected
    own = {"pose": "oracle", "a": "learned", "b": "scripted", "diff": -0.5, "ci95": [-0.9, 0.1],
           "mcnemar_p": 0.01}  # fmt: skip
    assert (
        cp._differences({**small_report, "differences": [own]}, "scripted")[("learned", "oracle")]
        is own
    )  # the report's own numbers win


def test_each_noise_kind_gets_its_own_axis_from_the_true_pose(small_report):
    curves = cp._noise_points(small_report)
    assert list(curves) == ["position", "heading"]
    for kind, per_policy in curves.items():
        for points in per_policy.values():
            assert [p["x"] for p in points] == ([0.0, 2.0] if kind == "position" else [0.0, 20.0])
            assert all(cp.noise_kind(*p["noise"]) in (kind, None) for p in points)


def test_older_reports_without_headings_are_joint_noise_and_plot(tmp_path):
    """``noisy@S`` of older reports: S metres with ``S * 500`` degrees, one joint axis."""
    levels = ((0.005, "1111111110"), (0.02, "1110011100"))
    results = [_record(p, f"noisy@{s}", o, (s, None)) for s, o in levels for p in ("a", "rl")]
    for r in results:
        del r["label"], r["training"], r["noise_yaw_deg"]
    report = _report(results, noise_heading_deg_per_m=500.0)
    del report["reference"]  # older reports: the first policy is the reference
    assert set(cp._differences(report, "a")) == {("rl", "noisy@0.005"), ("rl", "noisy@0.02")}
    curves = cp._noise_points(report)
    assert list(curves) == ["both"]
    assert [p["noise"] for p in curves["both"]["rl"]] == [(0.005, 2.5), (0.02, 10.0)]
    assert cp.plot_comparison(report, tmp_path / "old.png") == [
        "success", "differences", "objects", "noise_both"
    ]  # fmt: skip


def test_one_policy_has_no_differences_and_no_noise_no_noise_panel(tmp_path):
    report = _report([_record("scripted", "manifold", "1101111111")])
    assert cp.plot_comparison(report, tmp_path / "one.png") == ["success", "objects"]
    with pytest.raises(ValueError, match="no results"):
        cp.plot_comparison({**report, "results": []}, tmp_path / "none.png")


def test_conditions_are_named_for_what_they_are():
    assert cp.condition_title("noisy@0.02:0", (0.02, 0.0)) == "position noise σ 2 cm"
    assert cp.condition_title("noisy@0:20", (0.0, 20.0), short=True) == "heading 20°"
    assert cp.condition_title("oracle", (0.0, 0.0)) == "true pose"
    assert "chance" in cp.condition_title("chance", None)
    assert cp.noise_kind(0.01, 5.0) == "both" and cp.noise_kind(0.0, 0.0) is None


def test_the_published_comparison_redraws_from_its_json(tmp_path):
    report = json.loads((RESULTS / "compare.json").read_text())
    panels = cp.plot_comparison(report, tmp_path / "compare.png")
    assert panels[:3] == ["success", "differences", "objects"]
    assert {"noise_position", "noise_heading"} <= set(panels)
    assert np.isfinite(imread(tmp_path / "compare.png")).all()


def test_the_benchmark_redraws_a_gzipped_report_without_running_episodes(tmp_path, capsys):
    import gzip
    import runpy

    from pose.fileio import atomic_write_json

    out = tmp_path / "compare_copy.json.gz"
    atomic_write_json(out, json.loads((RESULTS / "compare.json").read_text()))
    script = RESULTS.parent / "compare.py"
    main = runpy.run_path(str(script), run_name="benchmark_under_test")["main"]
    assert main(["--replot", "--out", str(out)]) == 0
    assert (tmp_path / "compare_copy.png").read_bytes()[:4] == b"\x89PNG"
    assert "written" in capsys.readouterr().out and gzip.open(out).read(1) == b"{"
