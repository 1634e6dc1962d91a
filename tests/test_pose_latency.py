"""Side-by-side single-thread latency measurement (the 30 ms target's benchmark)."""

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from pose.registry import make_from_spec
from pose.view import PoseEstimate
from scorbot_gym.experiments.latency import stage_timings, summarize_latency, time_predictions

ROOT = Path(__file__).resolve().parents[1]


class _Logged:
    """Wraps a fitted estimator: logs each predict call, optionally sleeping first."""

    def __init__(self, name, est, log, sleep_s=0.0):
        self.name, self.est, self.log, self.sleep_s = name, est, log, sleep_s

    def predict(self, view):
        self.log.append(self.name)
        time.sleep(self.sleep_s)
        return self.est.predict(view)


@pytest.fixture(scope="module")
def fitted_pair(can_views):
    train, poses, test = can_views
    chance = make_from_spec("chance").fit(train, poses)
    pnp = make_from_spec("sift-pnp").fit(train, poses)
    return chance, pnp, [lv.view for lv in test]


def test_times_every_estimator_on_every_view_interleaved(fitted_pair):
    chance, pnp, views = fitted_pair
    log = []
    ests = {"chance": _Logged("chance", chance, log), "pnp": _Logged("pnp", pnp, log),
            "slow": _Logged("slow", chance, log, sleep_s=0.02)}  # fmt: skip
    ms = time_predictions(ests, views, repeats=2)
    assert set(ms) == set(ests) and all(m.shape == (len(views),) for m in ms.values())
    assert all(np.all(m > 0) for m in ms.values())
    assert np.all(ms["slow"] >= 20.0)  # a sleep lasts at least its duration: the timer is real
    # one untimed call each, then repeats x views calls each
    assert [log.count(n) for n in ests] == [1 + 2 * len(views)] * 3
    # the estimators take turns: each goes first on some view
    timed = log[3:]
    firsts = {timed[i] for i in range(0, len(timed), 3)}
    assert firsts == set(ests)


def test_stage_timings_are_the_estimators_own_clocks(fitted_pair):
    chance, pnp, views = fitted_pair
    stages = stage_timings(pnp, views)
    assert "total" in stages and len(stages) > 1
    n_valid = sum(pnp.predict(v).valid for v in views)
    assert all(len(v) == n_valid and min(v) >= 0 for v in stages.values())
    assert set(stage_timings(chance, views)) == {"constant", "total"}

    class NoClock:  # an estimator that reports no stage times
        def predict(self, view):
            return PoseEstimate(np.eye(3), np.zeros(3), 1.0, True)

    assert stage_timings(NoClock(), views) == {}


def test_summary_ratio_is_paired_per_view():
    rows = summarize_latency(
        {"a": np.array([10.0, 20.0, 40.0]), "ref": np.array([5.0, 20.0, 10.0])}, reference="ref"
    )
    a, ref = rows
    assert a["median_ms"] == 20.0 and a["ratio_to_reference"] == 2.0  # median of 2, 1, 4
    assert ref["ratio_to_reference"] == 1.0 and a["n"] == 3 and a["max_ms"] == 40.0
    assert "ratio_to_reference" not in summarize_latency({"a": np.ones(2)})[0]


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: summarize_latency({"a": np.ones(2)}, reference="b"), "reference 'b'"),
        (lambda: summarize_latency({"a": np.ones(2), "b": np.ones(3)}, "b"), "same views"),
        (lambda: time_predictions({"a": None}, [None], repeats=0), "repeats"),
        (lambda: time_predictions({}, [None]), "at least one fitted"),
        (lambda: time_predictions({"a": None}, []), "at least one view"),
    ],
)
def test_bad_input_is_a_one_line_error(call, message):
    with pytest.raises(ValueError, match=message):
        call()


def test_pinning_leaves_one_core_and_one_thread():
    code = (
        "import json, os, cv2; from scorbot_gym.experiments.latency import pin_to_one_core; "
        "c = pin_to_one_core(); "
        "print(json.dumps([c, sorted(os.sched_getaffinity(0)), cv2.getNumThreads()]))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    core, affinity, threads = json.loads(out.stdout)
    assert affinity == [core] and threads == 1
    assert int(core) in os.sched_getaffinity(0)


@pytest.mark.slow
def test_benchmark_script_writes_paired_figures(tmp_path):
    out = tmp_path / "latency.json"
    cmd = [sys.executable, str(ROOT / "benchmarks" / "pose_latency.py"), "--protocols",
           "top-resting", "--objects", "potted_meat_can", "--estimators", "chance,pca-rbf",
           "--reference", "chance", "--views", "2", "--repeats", "1", "--jobs", "1",
           "--cache-dir", str(tmp_path / "cache"), "--json", str(out)]  # fmt: skip
    subprocess.run(cmd, check=True, capture_output=True, env={**os.environ, "MUJOCO_GL": "egl"})
    report = json.loads(out.read_text())
    rows = {r["estimator"]: r for r in report["results"]}
    assert set(rows) == {"chance", "pca-rbf"} and rows["chance"]["ratio_to_reference"] == 1.0
    assert all(r["n"] == 2 and r["median_ms"] > 0 and r["protocol"] == "top-resting"
               for r in rows.values())  # fmt: skip
    assert report["machine"]["threads"] == 1 and report["target_ms"] == 30.0
    assert all(isinstance(r["stages_median_ms"], dict) for r in rows.values())
    assert [f["estimator"] for f in report["fitting"]["top-resting"]] == ["chance", "pca-rbf"]
    bad = subprocess.run(cmd[:2] + ["--protocols", "nope"], capture_output=True, text=True)
    assert bad.returncode == 2 and "unknown protocols ['nope']" in bad.stderr
