"""Learning curves over seeds (:mod:`scorbot_gym.rl.curves`) from evaluation histories written
by hand: the fast tier's check of the module (the end-to-end one trains two seeds, marked slow
in ``test_rl_workflow.py``)."""

import json

import numpy as np
import pytest
from scipy import stats

from scorbot_gym.rl import runs
from scorbot_gym.rl.curves import learning_curves, plot_learning_curves


def _run(folder, seed: int, evals: list[tuple[int, float, float]]):
    """A run folder with only what the curves read: the checkpoint's evaluation history."""
    state = {
        "config": {"seed": seed, "algo": "sac", "timesteps": evals[-1][0]},
        "eval": [{"timesteps": t, "wall_s": w, "success_rate": s} for t, w, s in evals],
    }
    (folder / runs.CHECKPOINT).mkdir(parents=True)
    (folder / runs.CHECKPOINT / runs.STATE).write_text(json.dumps(state))
    return folder


def test_seeds_are_averaged_on_the_steps_they_all_reached_with_a_t_band(tmp_path):
    seeds = tmp_path / "seeds"
    _run(seeds / "seed_0", 0, [(100, 10.0, 0.2), (200, 20.0, 0.4), (300, 30.0, 0.6)])
    _run(seeds / "seed_1", 1, [(100, 12.0, 0.1), (200, 24.0, 0.2)])  # stopped earlier
    report = learning_curves({"sac": [seeds]}, points=5)
    arm = report["sac"]
    assert arm["seeds"] == [0, 1] and arm["final_success_rate"] == [0.6, 0.2]
    # runs from before the stall diagnostic was recorded: unknown, not zero
    assert arm["final_failed_grasp_distance_m"] == [{"final": None, "closest": None}] * 2
    steps = arm["by_timesteps"]
    assert steps["timesteps"] == [100.0, 200.0]  # no extrapolation past seed 1's last point
    np.testing.assert_allclose(steps["mean"], [0.15, 0.3])
    half = stats.t.ppf(0.975, 1) * np.std([0.2, 0.1], ddof=1) / np.sqrt(2)
    assert steps["ci95_low"][0] == 0.0  # clipped at 0
    np.testing.assert_allclose(steps["ci95_high"][0], 0.15 + half)
    wall = arm["by_wall_s"]
    assert wall["wall_s"][0] == 12.0 and wall["wall_s"][-1] == 24.0 and len(wall["wall_s"]) == 5
    plot_learning_curves(report, tmp_path / "c.png")
    assert (tmp_path / "c.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_last_evaluations_stall_diagnostic_is_reported_per_seed(tmp_path):
    run = _run(tmp_path / "r", 0, [(100, 1.0, 0.0), (200, 2.0, 0.1)])
    path = run / runs.CHECKPOINT / runs.STATE
    state = json.loads(path.read_text())
    state["eval"][-1].update(
        failed_median_final_grasp_distance_m=0.061, failed_median_closest_grasp_distance_m=0.04
    )
    path.write_text(json.dumps(state))
    arm = learning_curves({"r": [run]})["r"]
    assert arm["final_failed_grasp_distance_m"] == [{"final": 0.061, "closest": 0.04}]


def test_each_seed_reports_its_best_evaluation_and_when_it_first_reached_50_and_80(tmp_path):
    """A curve that is not monotone: the peak is the first best evaluation, not the last."""
    evals = [(100, 1.0, 0.0), (200, 2.0, 0.6), (300, 3.0, 0.9), (400, 4.0, 0.9), (500, 5.0, 0.3)]
    run = _run(tmp_path / "r", 0, evals)
    arm = learning_curves({"r": [run]})["r"]
    assert arm["peak"] == [{"success_rate": 0.9, "timesteps": 300}]
    assert arm["first_reached"]["0.5"]["timesteps"] == [200]
    assert arm["first_reached"]["0.8"] == {"timesteps": [300], "wall_s": [3.0], "seeds_reached": 1}
    assert arm["final_success_rate"] == [0.3]
    assert arm["per_seed"] == [
        {
            "seed": 0,
            "timesteps": [100, 200, 300, 400, 500],
            "success_rate": [0.0, 0.6, 0.9, 0.9, 0.3],
        }
    ]


def test_one_seed_has_no_band_and_a_run_without_evaluations_is_a_clear_error(tmp_path):
    one = _run(tmp_path / "one", 3, [(50, 1.0, 0.5), (100, 2.0, 1.0)])
    curve = learning_curves({"one": [one]})["one"]["by_timesteps"]
    assert curve["ci95_low"] is None and curve["mean"] == [0.5, 1.0]
    empty = _run(tmp_path / "empty", 4, [(1, 1.0, 0.0)])
    (empty / runs.CHECKPOINT / runs.STATE).write_text(json.dumps({"config": {}, "eval": []}))
    with pytest.raises(ValueError, match="no evaluations recorded yet"):
        learning_curves({"empty": [empty]})


@pytest.mark.parametrize(
    "other",
    [
        {"reward_type": "normalized_dense"},
        # the same reward built for another discount: its returns are on another scale
        {"reward_type": "normalized_pregrasp", "reward_gamma": 0.8},
    ],
)
def test_returns_of_different_rewards_are_not_drawn_on_one_axis(tmp_path, other):
    """Two arms on different rewards: the figure shows success only (one row of panels)."""
    import struct

    runs_ = {}
    for name, reward in (("a", {"reward_type": "normalized_pregrasp"}), ("b", other)):
        run = _run(tmp_path / name, 0, [(100, 1.0, 0.0), (200, 2.0, 0.5)])
        path = run / runs.CHECKPOINT / runs.STATE
        state = json.loads(path.read_text())
        state["config"]["hyperparams"] = reward
        for e in state["eval"]:
            e["mean_return"] = 0.1
        path.write_text(json.dumps(state))
        runs_[name] = [run]

    def height(report) -> int:
        plot_learning_curves(report, tmp_path / "c.png")
        return struct.unpack(">I", (tmp_path / "c.png").read_bytes()[20:24])[0]

    both = learning_curves(runs_)
    one = learning_curves({"a": runs_["a"]})
    assert "return_by_timesteps" in both["a"] and "return_by_timesteps" in both["b"]
    assert height(both) < 0.6 * height(one)  # the return row is left out


def test_every_training_preset_is_a_valid_run():
    """A preset with a misspelt setting or value fails here, not hours into a sweep."""
    import runpy
    from pathlib import Path

    from scorbot_gym.perception.oracle import OccludedOraclePoseSource
    from scorbot_gym.rl.training import TrainConfig, make_policy_env

    script = Path(__file__).resolve().parents[1] / "benchmarks" / "learning_curves.py"
    presets = runpy.run_path(str(script), run_name="presets_under_test")["PRESETS"]
    for label, preset in presets.items():
        config = TrainConfig(**preset).validate()
        assert config.resolved_hyperparams(), label
    occluded = TrainConfig(**presets["scratch_occluded"]).validate()
    env = make_policy_env(occluded)
    assert isinstance(env.get_wrapper_attr("source"), OccludedOraclePoseSource)
    env.close()
