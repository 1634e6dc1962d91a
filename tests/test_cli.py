"""The ``scorbot-gym`` command line, run in-process with real episodes."""

import json

import pytest

from scorbot_gym.cli import main


@pytest.mark.slow
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


def test_rollout_rejects_bad_input_before_running(tmp_path, capsys):
    def rejected(*argv: str) -> str:
        with pytest.raises(SystemExit) as exc:
            main(["rollout", *argv])
        assert exc.value.code == 2
        return capsys.readouterr().err

    assert "--episodes: must be an integer >= 1" in rejected("--episodes", "0")
    assert "unknown 'teapot'; valid: tomato_soup_can" in rejected("--objects", "teapot")
    assert "invalid choice: 'nonsense'" in rejected("--camera", "nonsense")
    assert "invalid choice: 'telepathy'" in rejected("--policy", "telepathy")
    assert "must be a probability" in rejected("--pose", "noisy", "--dropout", "2")
    # Checks that need more than one argument run before any episode, not after the rollout.
    assert main(["rollout", "--video", str(tmp_path / "x.avi"), "--no-progress"]) == 2
    assert "--video must end in" in capsys.readouterr().err
    assert main(["rollout", "--overlay", "--no-progress"]) == 2
    assert "--overlay draws on the video" in capsys.readouterr().err
    assert main(["rollout", "--pose", "manifold", "--pose-model", str(tmp_path / "no.npz")]) == 2
    assert "no such file" in capsys.readouterr().err
    assert main(["rollout", "--yaw-sigma-deg", "5", "--no-progress"]) == 2
    assert "only apply to pose 'noisy_oracle'" in capsys.readouterr().err
    assert main(["rollout", "--fallback-camera", "side", "--no-progress"]) == 2
    assert "only apply to pose 'manifold'" in capsys.readouterr().err
    assert main(["rollout", "--pose", "manifold", "--fallback-camera", "top"]) == 2
    assert "must differ from the pose camera" in capsys.readouterr().err
    assert main(["rollout", "--perturb", "glare=1", "--no-progress"]) == 2
    assert "bad perturbation 'glare=1'" in capsys.readouterr().err


def test_rollout_perturbation_reaches_the_env_and_the_summary():
    """``--perturb`` is the env's perturbation (the in-loop use of the axes), recorded in the
    summary and its configuration."""
    from scorbot_gym.cli import build_parser
    from scorbot_gym.cli.rollout import config_from_args
    from scorbot_gym.data.perturbations import Perturbation
    from scorbot_gym.evaluation.rollout import run_rollout

    args = build_parser().parse_args(
        ["rollout", "--perturb", "surfaces=1.0,noise_sigma=4", "--objects", "box",
         "--episodes", "1", "--seed", "3"]
    )  # fmt: skip
    config = config_from_args(args)
    env = config.make_env()
    assert env.unwrapped.perturbation == Perturbation(surfaces=1.0, noise_sigma=4.0)
    env.close()
    summary, _ = run_rollout(config)
    assert summary["perturbation"] == "surfaces=1.0,noise_sigma=4"
    assert summary["config"]["perturbation"] == "surfaces=1.0,noise_sigma=4"


def test_rollout_regrasps_reach_the_scripted_controller_and_the_summary():
    """``--regrasps N`` configures the scripted controller's retries; the summary counts the
    episodes that retried; with a learned policy it is a one-line error."""
    from scorbot_gym.cli import build_parser
    from scorbot_gym.cli.rollout import config_from_args
    from scorbot_gym.evaluation.rollout import RolloutConfig, run_rollout

    argv = ["rollout", "--regrasps", "1", "--objects", "box", "--episodes", "1", "--seed", "3"]
    config = config_from_args(build_parser().parse_args(argv))
    env = config.make_env()
    assert config.make_policy(env).regrasps == 1
    env.close()
    summary, _ = run_rollout(config)
    assert summary["config"]["regrasps"] == 1
    assert summary["regrasps"] == {"episodes": 0, "successes": 0}  # a clean grasp: no retry
    with pytest.raises(ValueError, match="scripted policy only"):
        RolloutConfig(policy="learned", regrasps=1)
    with pytest.raises(SystemExit):
        main(["rollout", "--regrasps", "-1"])


def test_rollout_help_lists_objects_and_cameras(capsys):
    with pytest.raises(SystemExit):
        main(["rollout", "--help"])
    text = capsys.readouterr().out
    assert "banana" in text and "eye_in_hand" in text and "--disturb" in text


def test_object_lists_accept_spaces_and_commas(tmp_path):
    from scorbot_gym.cli import build_parser

    parser = build_parser()
    a = parser.parse_args(["rollout", "--objects", "banana", "box"])
    b = parser.parse_args(["rollout", "--objects", "banana,box"])
    assert a.objects == b.objects == ["banana", "box"]


def test_doctor_reports_backend_and_fps(capsys):
    assert main(["doctor", "--frames", "2"]) == 0
    text = capsys.readouterr().out
    assert "MUJOCO_GL=egl" in text and "rendering: ok" in text and "frames/s" in text
