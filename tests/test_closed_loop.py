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


def test_manifold_pose_needs_a_model(capsys):
    assert main(["rollout", "--pose", "manifold", "--episodes", "1", "--no-progress"]) == 2
    assert "--pose-model" in capsys.readouterr().err
