"""The ``scorbot-gym`` command line, run in-process with real episodes."""

import json

import pytest

from scorbot_gym.cli import main


def test_rollout_prints_summary_and_writes_json_and_gif(tmp_path, capsys):
    out, gif = tmp_path / "summary.json", tmp_path / "first.gif"
    code = main(
        [
            "rollout",
            "--policy",
            "scripted",
            "--pose",
            "oracle",
            "--episodes",
            "2",
            "--object",
            "box",
            "--seed",
            "3",
            "--json",
            str(out),
            "--camera",
            "top",
            "--video",
            str(gif),
            "--no-progress",
        ]
    )
    assert code == 0
    text = capsys.readouterr().out
    assert "success rate" in text and "95% CI" in text and "failures: missed" in text
    summary = json.loads(out.read_text())
    assert summary["episodes"] == 2 and summary["success_rate"] == 1.0
    assert len(summary["results"]) == 2 and summary["policy"] == "scripted"
    assert gif.stat().st_size > 1000 and gif.read_bytes()[:3] == b"GIF"


def test_rollout_rejects_bad_input(tmp_path, capsys):
    assert main(["rollout", "--episodes", "0"]) == 2
    assert "--episodes must be >= 1" in capsys.readouterr().err
    assert main(["rollout", "--episodes", "1", "--object", "teapot", "--no-progress"]) == 2
    assert "valid objects" in capsys.readouterr().err
    assert (
        main(
            [
                "rollout",
                "--episodes",
                "1",
                "--object",
                "box",
                "--no-progress",
                "--video",
                str(tmp_path / "x.avi"),
            ]
        )
        == 2
    )
    assert "--video must end in" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["rollout", "--policy", "telepathy"])


def test_doctor_reports_backend_and_fps(capsys):
    assert main(["doctor", "--frames", "2"]) == 0
    text = capsys.readouterr().out
    assert "MUJOCO_GL=egl" in text and "rendering: ok" in text and "frames/s" in text
