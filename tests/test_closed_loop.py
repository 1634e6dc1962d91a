"""Simulator -> view -> estimator -> estimate -> controller -> action, end to end."""

import json

import pytest

from scorbot_gym.cli import main


@pytest.mark.slow
def test_scripted_grasp_from_estimated_pose(tmp_path, capsys):
    model, summary = tmp_path / "box.npz", tmp_path / "summary.json"
    assert (
        main(
            [
                "pose",
                "train",
                "--objects",
                "box",
                "--views",
                "108",
                "--width",
                "320",
                "--height",
                "240",
                "--out",
                str(model),
                "--cache-dir",
                str(tmp_path),
                "--quiet",
            ]
        )
        == 0
    )
    assert (
        main(
            [
                "rollout",
                "--pose",
                "manifold",
                "--pose-model",
                str(model),
                "--object",
                "box",
                "--estimate-every",
                "0",
                "--episodes",
                "3",
                "--seed",
                "5",
                "--json",
                str(summary),
                "--no-progress",
            ]
        )
        == 0
    )
    out = json.loads(summary.read_text())
    assert out["pose_source"] == "manifold" and out["episodes"] == 3
    perception = out["perception"]
    assert perception["valid_rate"] == 1.0 and perception["estimates"] == 3
    assert perception["median_rot_err_deg"] < 5.0
    assert perception["median_pos_err_cm"] < 1.0
    assert perception["median_estimate_ms"] > 0.0
    assert out["success_rate"] == 1.0
    assert "median rotation error" in capsys.readouterr().out


@pytest.mark.slow
def test_disturbed_episode_only_the_servoing_controller_grasps():
    """A seeded push during the approach: re-estimating every step follows the object, the
    estimate-once controller grasps where the object was."""
    from scorbot_gym.evaluation.rollout import RolloutConfig, run_rollout

    base = dict(pose="oracle", disturbance="push", objects=("box",), episodes=1, seed=5)
    servo, _ = run_rollout(RolloutConfig(estimate_every=1, **base))
    once, results = run_rollout(RolloutConfig(estimate_every=0, **base))
    assert servo["success_rate"] == 1.0
    assert once["success_rate"] == 0.0 and results[0].failure_cause in ("missed", "dropped")
