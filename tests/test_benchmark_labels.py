"""Figures labelled for what they are (issue 51, "true labels"): the closed-loop table's blind
arms by what they ignore, speed ratios on CPU time with their pairs, ranges and render settings,
and a step timing whose note says what was timed."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pose.fileio import atomic_write_json

ROOT = Path(__file__).resolve().parents[1]
BENCHMARKS = ROOT / "benchmarks"
RESULTS = BENCHMARKS / "results"
sys.path.insert(0, str(BENCHMARKS))
sys.path.insert(0, str(BENCHMARKS / "peers"))

import env_step  # noqa: E402
import time_env  # noqa: E402

BLIND = {
    "rotation-blind (true position, constant rotation)": {"pose": "oracle_position"},
    "rotation-blind (image position, constant rotation)": {
        "pose": "manifold",
        "estimator": "chance",
        "recognize": True,
    },
    "image-blind (constant pose, identity given)": {"pose": "constant", "recognize": False},
}


def test_the_closed_loop_report_has_each_blind_arm_on_the_main_arms_episodes():
    report = json.loads((RESULTS / "closed_loop.json").read_text())
    arms, main = report["arms"], report["arms"]["manifold"]
    for label, config in BLIND.items():
        arm = arms[label]
        assert arm["label"] == label and arm["episodes"] == main["episodes"] == 220
        assert arm["seed"] == main["seed"] == report["seed"] == 1000
        assert {k: arm["config"][k] for k in config} == config
        assert arm["config"]["objects"] is None  # the whole catalogue, as the main arm
    assert "chance (image-blind estimator)" not in arms
    # blind to more is worth less: image-blind < rotation-blind (image) < the estimator
    rates = [arms[k]["success_rate"] for k in BLIND]
    assert rates[2] < rates[1] < main["success_rate"] <= arms["oracle"]["success_rate"]


@pytest.mark.slow
def test_merging_an_older_report_gives_its_arm_the_label_of_now(tmp_path):
    whole = json.loads((RESULTS / "closed_loop.json").read_text())
    now = "rotation-blind (image position, constant rotation)"
    old = {**whole["arms"][now], "label": "chance (image-blind estimator)"}
    first = {**whole, "arms": {"oracle": whole["arms"]["oracle"],
                               "chance (image-blind estimator)": old}}  # fmt: skip
    second = {**whole, "arms": {"manifold": whole["arms"]["manifold"]}}
    second["robustness"] = {"yaw": [], "pos": []}
    parts = [tmp_path / "old.json", tmp_path / "new.json"]
    for path, part in zip(parts, (first, second), strict=True):
        atomic_write_json(path, part)
    out = tmp_path / "merged.json"
    env = {**os.environ, "MUJOCO_GL": "egl", "PYTHONPATH": str(ROOT)}
    proc = subprocess.run(
        [sys.executable, str(BENCHMARKS / "closed_loop.py"), "--merge", *map(str, parts),
         "--out", str(out)],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=180,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    merged = json.loads(out.read_text())["arms"]
    assert list(merged) == ["oracle", "manifold", now]  # the run's order, the label of now
    assert merged[now]["label"] == now and merged[now]["successes"] == old["successes"]


def _run(cpu: float, wall: float, msaa: int = 0) -> dict:
    return {"steps_per_cpu_second": cpu, "steps_per_second": wall,
            "render_settings": {"msaa_samples": msaa}}  # fmt: skip


def test_paired_ratios_are_on_cpu_time_run_against_run_with_their_range():
    ours = [_run(200, 100), _run(300, 50), _run(250, 125), {"error": "exit 1"}]
    theirs = [_run(100, 100, 4), _run(100, 100, 4), _run(125, 25, 4), _run(1, 1, 4)]
    r = env_step.paired_ratio(ours, theirs)
    assert r["pairs"] == 3 and r["cpu_ratio_runs"] == [2.0, 3.0, 2.0]
    assert (r["cpu_ratio_median"], r["cpu_ratio_min"], r["cpu_ratio_max"]) == (2.0, 2.0, 3.0)
    assert r["wall_ratio_runs"] == [1.0, 0.5, 5.0] and r["wall_ratio_median"] == 1.0
    assert r["render_settings"] == {"numerator": {"msaa_samples": 0},
                                    "denominator": {"msaa_samples": 4}}  # fmt: skip
    assert env_step.paired_ratio([{"error": "x"}], [_run(1, 1)]) == {"pairs": 0}


def test_the_committed_speed_ratios_say_what_they_compare():
    report = json.loads((RESULTS / "env_step.json").read_text())
    ratios = {(r["setting"], r["comparison"]): r for r in report["ratios"]}
    assert set(ratios) == {(s, c) for s, c, _, _ in env_step.RATIOS}
    for r in ratios.values():
        assert r["pairs"] >= 5 and len(r["cpu_ratio_runs"]) == r["pairs"]
        assert r["cpu_ratio_min"] <= r["cpu_ratio_median"] <= r["cpu_ratio_max"]
    shipped = ratios[("camera_320x240", "ScorbotGrasp-v0 / Fetch, as shipped")]
    off = ratios[("camera_320x240", "ScorbotGrasp-v0 / Fetch, MSAA off in both")]
    on = ratios[("camera_320x240", "ScorbotGrasp-v0 / Fetch, 4x MSAA in both")]
    msaa = lambda r: [r["render_settings"][k]["msaa_samples"] for k in ("numerator", "denominator")]  # noqa: E731
    assert (msaa(shipped), msaa(off), msaa(on)) == ([0, 4], [0, 0], [4, 4])
    for r in (shipped, off, on):
        for side in r["render_settings"].values():
            assert {"msaa_samples", "shadows_rendered", "reflective_materials"} <= set(side)
            assert not side["shadows_rendered"] and side["reflective_materials"] == 0


def test_the_committed_wrapper_timing_measures_with_and_without_the_image():
    report = json.loads((RESULTS / "wrapper_step.json").read_text())
    for setting, image in (("no_images", False), ("camera_320x240", True)):
        timed = report["step"][setting]
        for env in ("ScorbotGrasp-v0", "ScorbotGrasp-v0/pose-oracle"):
            assert ("image = the 'top' camera" in timed[env]["note"]) is image
        ratio = timed["wrapped_over_bare"]
        assert ratio["pairs"] >= 5
        assert ratio["cpu_time_ratio_min"] <= ratio["cpu_time_ratio_median"]
        assert ratio["cpu_time_ratio_median"] <= ratio["cpu_time_ratio_max"]


@pytest.mark.slow
def test_the_matched_msaa_variant_renders_with_multisampling_and_records_it():
    frames = {}
    for msaa in (None, 4):
        timed = time_env.scorbot(True, msaa=msaa)
        try:
            obs, _ = timed.env.reset(seed=0)
            frames[msaa] = obs["top_rgb"].astype(int)
            assert timed.render_settings["msaa_samples"] == (msaa or 0)
            assert "image = the 'top' camera" in timed.note
        finally:
            timed.env.close()
    edges = np.abs(frames[None] - frames[4]).sum(-1) > 0
    assert 0 < edges.mean() < 0.1  # antialiased edges, the same scene
    bare = time_env.scorbot(False)
    try:
        assert bare.note.startswith("no image")
    finally:
        bare.env.close()
