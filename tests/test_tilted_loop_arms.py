"""The tilted closed-loop benchmark's chance and baseline arms (the project's evaluation rule:
the image-blind answer and a simple baseline beside every estimator figure, symmetric objects
apart). Each arm is a pose source: the ``manifold`` source running another model set, which a
:class:`~pose.model_set.PoseModelSet` file of any registered estimator makes possible."""

from __future__ import annotations

import argparse
import json
import runpy
from pathlib import Path

import numpy as np
import pytest

from pose.baselines import ChanceEstimator
from pose.manifold.estimator import PoseManifoldEstimator
from pose.model_set import PoseModelSet
from pose.serialization import load_arrays, save_arrays
from scorbot_gym.perception.training import IN_LOOP_TRAINING, RESTING_TRAINING

BENCHMARK = Path(__file__).resolve().parents[1] / "benchmarks" / "tilted_in_loop.py"


@pytest.fixture(scope="module")
def bench() -> dict:
    """The benchmark script's namespace (run as a module, not as ``__main__``)."""
    return runpy.run_path(str(BENCHMARK), run_name="benchmark_under_test")


def test_a_model_set_holds_a_baseline_and_reads_it_back(can_views, tmp_path):
    views, poses, test = can_views
    chance = ChanceEstimator().fit(views, poses)
    path = tmp_path / "chance.npz"
    PoseModelSet({"potted_meat_can": chance}, meta={"camera": "top"}).save(path)
    loaded = PoseModelSet.load(path)
    assert isinstance(loaded["potted_meat_can"], ChanceEstimator)
    assert loaded.meta == {"camera": "top"}
    for lv in test:
        a, b = chance.predict(lv.view), loaded.predict(lv.view)
        assert a.valid and b.valid
        np.testing.assert_allclose(a.rotation, b.rotation)
        np.testing.assert_allclose(a.translation, b.translation)
    header, arrays = load_arrays(path)
    header["classes"] = ["NoSuchEstimator"]
    save_arrays(path, arrays, {k: v for k, v in header.items() if not k.startswith("format")})
    with pytest.raises(ValueError, match="unknown estimator class 'NoSuchEstimator'"):
        PoseModelSet.load(path)


def _arm(label: str, tilt: float, ok: int, valid: int, hits: float, split: bool) -> dict:
    arm = {
        "label": label, "tilt_deg": tilt, "episodes": 2, "successes": ok,
        "estimates_valid": valid, "success_5deg_of_valid_estimates": hits,
        "perception": {"median_rot_err_deg": 1.5, "median_estimate_ms": 9.0},
        "per_object": {"banana": {"episodes": 1, "successes": ok - 1},
                       "cylinder": {"episodes": 1, "successes": 1}},
    }  # fmt: skip
    if split:
        arm["median_rot_err_deg"] = 1.5
        groups = {"none": ["banana"], "axial": ["cylinder"], "discrete": [], "symmetric": []}
        arm["by_symmetry"] = {
            g: {"objects": o, "episodes": len(o), "successes": ok if g == "none" else 0,
                "estimates_valid": valid if o else 0,
                "success_5deg_of_valid_estimates": hits if o else None,
                "median_rot_err_deg": 1.5 if o else None}
            for g, o in groups.items()
        }  # fmt: skip
    return arm


def test_new_arms_merge_with_the_arms_measured_before(bench):
    """A section written before the split (no ``runs``, no ``by_symmetry``) keeps its arms as
    measured; the totals cover every arm, the new ones with their symmetry split."""
    args = argparse.Namespace(
        arms=["chance"], objects=None, tilts=[20.0], episodes=2, seed=7, recognize=False
    )
    old = {
        "objects": "catalogue", "tilts_deg": [20.0], "episodes_per_tilt": 2, "seed": 7,
        "arms": [_arm("oracle", 20.0, 2, 40, 1.0, False),
                 _arm("manifold", 20.0, 1, 10, 0.9, False)],
        "wall_s": 30.0, "jobs": 2, "machine": {"cpus": 2},
    }  # fmt: skip
    assert bench["_same_loop"](old, args)
    new = {"arms": [_arm("chance", 20.0, 1, 20, 0.25, True)], "run": {"arms": ["chance"]}}
    section = bench["merge_loop"](new, old, args)
    assert [a["label"] for a in section["arms"]] == ["oracle", "manifold", "chance"]
    assert section["arms"][0]["successes"] == 2  # as measured
    assert section["runs"] == [
        {"wall_s": 30.0, "jobs": 2, "machine": {"cpus": 2}, "arms": ["oracle", "manifold"]},
        {"arms": ["chance"]},
    ]
    totals = section["totals"]
    assert set(totals) == {"oracle_tilted", "manifold_tilted", "chance_tilted"}
    assert totals["manifold_tilted"]["grasp_success"] == 0.5
    old_split = totals["manifold_tilted"]["by_symmetry"]  # grasps from per_object
    assert old_split["none"]["grasp_success"] == 0.0 and old_split["axial"]["grasp_success"] == 1
    assert not old_split["none"]["estimates_split"]
    assert "success_5deg_of_valid_estimates" not in old_split["none"]  # not recorded then
    chance = totals["chance_tilted"]
    assert chance["success_5deg_of_valid_estimates"] == 0.25
    assert chance["by_symmetry"]["none"]["objects"] == ["banana"]
    assert chance["by_symmetry"]["none"]["grasp_success"] == 1.0
    assert chance["by_symmetry"]["none"]["estimates_split"]
    assert chance["by_symmetry"]["discrete"]["grasp_success"] is None  # no such episode
    # another size: nothing is merged
    assert not bench["_same_loop"](old, argparse.Namespace(**{**vars(args), "episodes": 3}))


def test_an_unknown_arm_is_a_one_line_error(bench):
    with pytest.raises(ValueError, match="unknown arm 'chancy'; the arms: oracle, manifold"):
        bench["arm_models"]("chancy", ("box",), 1)


@pytest.mark.slow
def test_one_episode_per_arm_writes_the_documented_keys(bench, tmp_path):
    """Every arm is constructible (its model file) and a one-episode run of each writes the
    figures the README quotes; a later run of another arm keeps them."""
    out = tmp_path / "loop.json"
    common = ["--out", str(out), "loop", "--episodes", "1", "--tilts", "20", "--objects", "box"]
    assert bench["main"]([*common, "--arms", "chance", "resting"]) == 0
    chance = PoseModelSet.load(bench["arm_models"]("chance", ("box",), 1, progress=False))
    assert chance.object_names == ["box"] and isinstance(chance["box"], ChanceEstimator)
    assert chance.meta["views_of"] == IN_LOOP_TRAINING.to_dict()  # the manifold's views
    resting = PoseModelSet.load(bench["arm_models"]("resting", ("box",), 1, progress=False))
    assert isinstance(resting["box"], PoseManifoldEstimator)
    assert resting.meta["training"] == RESTING_TRAINING.to_dict()
    assert bench["main"](["--overwrite", *common, "--arms", "oracle"]) == 0  # updates its file
    section = json.loads(out.read_text())["loop"]
    assert {a["label"] for a in section["arms"]} == {"chance", "resting", "oracle"}
    for arm in section["arms"]:
        assert arm["episodes"] == 1 and arm["tilt_deg"] == 20.0
        assert arm["estimates_valid"] > 0
        assert 0.0 <= arm["success_5deg_of_valid_estimates"] <= 1.0
        assert arm["median_rot_err_deg"] >= 0.0
        assert set(arm["by_symmetry"]) == {"none", "axial", "discrete", "symmetric"}
        assert arm["by_symmetry"]["discrete"]["objects"] == ["box"]
    for label in ("chance", "resting", "oracle"):
        total = section["totals"][f"{label}_tilted"]
        for key in ("grasp_success", "grasp_success_ci95", "success_5deg_of_valid_estimates",
                    "median_rot_err_deg_of_arms", "by_symmetry"):  # fmt: skip
            assert key in total, (label, key)
        assert total["by_symmetry"]["symmetric"]["episodes"] == 1
    assert section["totals"]["oracle_tilted"]["success_5deg_of_valid_estimates"] == 1.0
    assert [r["arms"] for r in section["runs"]] == [["chance", "resting"], ["oracle"]]
