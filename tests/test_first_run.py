"""The first run is a visible step (issue #51 item 2): progress while the default models train,
``scorbot-gym doctor`` saying whether they are ready, ``pose train --defaults`` building them
ahead into the cache the main job reads."""

import inspect
import io
import re
from dataclasses import replace

import pytest

from scorbot_gym._progress import ItemProgress
from scorbot_gym.cli import main
from scorbot_gym.perception import defaults
from scorbot_gym.perception.training import TrainingSet, default_pose_models, train_models

#: the main job's models, made tiny: two objects, a heading every 60 degrees
TINY = replace(defaults.MAIN_JOB, objects=("box", "banana"), training=TrainingSet(yaw_step_deg=60))


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_off_a_terminal_each_finished_object_gets_a_line_with_elapsed_and_left():
    out = io.StringIO()
    with ItemProgress("training pose models (top 320x240)", 3, stream=out) as bar:
        bar.update("box", "24 views, render 3 s, fit 2 s")
        bar.update("banana")
        bar.update("golf_ball")
    lines = out.getvalue().splitlines()
    assert len(lines) == 3 and "\r" not in out.getvalue()
    assert lines[0].startswith("training pose models (top 320x240): 1/3 box (24 views,")
    assert re.search(r"0:0\d elapsed, about 0:0\d left$", lines[0]), lines[0]
    assert lines[2].endswith("elapsed") and "2/3 banana" in lines[1]  # nothing left at 3/3


def test_on_a_terminal_it_is_a_bar_naming_what_and_how_far():
    out = _Terminal()
    with ItemProgress("training pose models (top 320x240)", 2, stream=out) as bar:
        assert bar.interactive
        bar.update("box")
        bar.update("banana")
    text = out.getvalue()
    assert "training pose models (top 320x240)" in text and "2/2" in text and "banana" in text
    quiet = io.StringIO()
    with ItemProgress("x", 2, enabled=False, stream=quiet) as bar:
        bar.update("box")
    assert quiet.getvalue() == "" and not bar.interactive


def test_training_reports_each_object_on_stderr(capsys, tmp_path):
    train_models(["box"], n_views=12, cache_dir=str(tmp_path), progress=True)
    err = capsys.readouterr().err
    assert re.search(r"training pose models \(top 320x240\): 1/1 box \(\d+ views, render", err)


def test_the_defaults_are_what_the_main_job_uses():
    from scorbot_gym.evaluation import compare
    from scorbot_gym.evaluation.rollout import RolloutConfig

    main_job = RolloutConfig(pose="manifold", recognize=True)
    spec = defaults.MAIN_JOB
    assert main_job.pose_cameras == spec.recognition_cameras == compare.MANIFOLD_CAMERAS
    assert (main_job.pose_cameras[0], *main_job.pose_size) == (spec.camera, spec.width, spec.height)
    assert main_job.recognizer == spec.recognizer == compare.MANIFOLD_RECOGNIZER == "appearance"
    assert [e.what.split(",")[0] for e in defaults.cache_entries()] == ["pose models"]
    assert inspect.signature(default_pose_models).parameters["training"].default == spec.training
    assert spec.objects is None  # the whole catalogue


@pytest.mark.slow
@pytest.mark.parametrize("recognizer", ["appearance", "flr+appearance"])
def test_doctor_then_defaults_then_the_main_job_finds_them(
    monkeypatch, tmp_path, capsys, recognizer
):
    """Doctor says missing; ``pose train --defaults`` builds exactly the entries doctor lists
    (the silhouettes only for a recogniser that uses FLR); doctor says ready with their sizes;
    the main job's own calls then build nothing."""
    from scorbot_gym.perception.recognizers import make_recognizer

    spec = replace(TINY, recognizer=recognizer)
    flr = "flr" in recognizer
    monkeypatch.setenv("SCORBOT_GYM_CACHE", str(tmp_path))
    monkeypatch.setattr(defaults, "MAIN_JOB", spec)
    assert main(["doctor", "--frames", "1"]) == 0
    out = capsys.readouterr().out
    entries = defaults.cache_entries(spec)
    assert len(entries) == 1 + flr
    assert out.count(": missing") == len(entries) and "scorbot-gym pose train --defaults" in out
    assert all(str(e.path) in out for e in entries)

    assert main(["pose", "train", "--defaults", "--jobs", "1"]) == 0
    captured = capsys.readouterr()
    assert "1/2 box" in captured.err and "2/2 banana" in captured.err  # a line per object
    assert ("rendering silhouettes" in captured.err) == flr
    assert all(e.present and e.size_bytes > 0 for e in entries)
    assert main(["doctor", "--frames", "1"]) == 0
    out = capsys.readouterr().out
    assert len(re.findall(r": ready, \d+\.\d MB", out)) == len(entries)

    files = sorted(p for p in tmp_path.rglob("*") if p.is_file())
    models = default_pose_models(objects=TINY.objects, training=TINY.training, progress=False)
    make_recognizer(recognizer, models, spec.recognition_cameras, spec.width, spec.height)
    assert sorted(p for p in tmp_path.rglob("*") if p.is_file()) == files  # nothing new built


def test_defaults_takes_no_options_that_choose_other_models(capsys):
    assert main(["pose", "train", "--defaults", "--views", "12", "--camera", "side"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "takes only --jobs and --quiet, got --views, --camera" in err
