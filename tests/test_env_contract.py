"""Every env ``make_env`` builds keeps Gymnasium's contract with every pose source (issue 50,
deliverable 3): ``gym.make(env.spec)`` rebuilds it (the pose source and its arguments are in
the wrapper's spec, a model set by its file, never as the object) and ``check_env`` passes."""

from __future__ import annotations

import os
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from scorbot_gym import make_env
from scorbot_gym.perception import pose_source_names
from scorbot_gym.perception.oracle import OraclePoseSource
from scorbot_gym.perception.references import CONTENT_FOLDER, content_digest, load_model_set
from scorbot_gym.wrappers import PoseEstimateObservation

OBJECTS = ["box", "tomato_soup_can"]
SMALL = {"image_width": 64, "image_height": 48}


@pytest.fixture(scope="module")
def models_file(tmp_path_factory) -> Path:
    """Two objects' pose models (top camera, 320 x 240), as `scorbot-gym pose train` writes them."""
    from scorbot_gym.perception.training import train_models

    path = tmp_path_factory.mktemp("models") / "two.npz"
    train_models(OBJECTS, n_views=72, progress=False)[0].save(path)
    return path


def _loaded(path: Path):
    """The model set in ``path``, read as a user reads it (so nothing remembers the file)."""
    from pose.model_set import PoseModelSet

    return PoseModelSet.load(path)


# Each registered pose source, as make_env builds it: its keywords (a model set object where
# one is needed) and the table it needs (the clutter sources: a target among distractors).
def _env_kwargs(source: str, models_file: Path) -> dict:
    if source == "oracle":
        return {"object_name": "box", "cameras": ["top"], **SMALL}
    if source in ("constant", "oracle_position"):  # blind arms: no image, identity given
        return {"pose_kwargs": {"yaw_deg": 30.0}, "objects": OBJECTS}
    if source == "noisy_oracle":
        noise = {"pos_sigma_m": 0.02, "yaw_sigma_deg": 7.0, "dropout": 0.1}
        return {"pose_kwargs": noise, "objects": OBJECTS, "distractors": 1}
    if source == "occluded_oracle":  # the hide range is a list: the spec keeps it as data
        hidden = {"pos_sigma_m": 0.01, "hide_distance_m": [0.05, 0.3]}
        return {"pose_kwargs": hidden, "objects": OBJECTS}
    models = {"models": load_model_set(models_file)}  # as the sources read a path
    if source == "manifold":
        return {"pose_kwargs": {**models, "recognizer": "appearance"}, "objects": OBJECTS,
                "identity": "recognize", "pose_cameras": ["top"]}  # fmt: skip
    return {"pose_kwargs": models, "objects": OBJECTS, "distractors": 1}


def test_every_registered_pose_source_is_covered():
    """A pose source added to the registry must be added here (and so to the contract)."""
    assert set(pose_source_names()) == {
        "oracle", "noisy_oracle", "manifold", "manifold_clutter", "largest_blob", "random_blob",
        "constant", "oracle_position", "occluded_oracle",
    }  # fmt: skip


@pytest.mark.slow
@pytest.mark.parametrize("source", sorted(pose_source_names()))
def test_gym_make_of_the_spec_rebuilds_the_env_and_check_env_passes(source, models_file):
    env = make_env(pose=source, **_env_kwargs(source, models_file))
    wrapper = env.spec.additional_wrappers[-1]
    assert wrapper.kwargs["source"] == source and "source_not_recorded" not in wrapper.kwargs
    if "models" in wrapper.kwargs:  # recorded by its file, not as the loaded object
        assert wrapper.kwargs["models"] == str(models_file.resolve())
    again = gym.make(env.spec)
    assert again.spec == env.spec
    assert again.observation_space == env.observation_space
    a, info_a = env.reset(seed=3)
    b, info_b = again.reset(seed=3)
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    assert info_a["perception"] == info_b["perception"]
    again.close()
    check_env(env, skip_render_check=True)  # makes the env again from its spec to close it
    env.close()


def test_the_spec_is_plain_data_and_survives_json(models_file):
    env = make_env(pose="manifold", pose_kwargs={"models": str(models_file)}, objects=OBJECTS)
    spec = gym.envs.registration.EnvSpec.from_json(env.spec.to_json())
    assert spec.additional_wrappers[-1].kwargs["models"] == str(models_file.resolve())
    again = gym.make(spec)
    assert again.observation_space == env.observation_space
    again.close()
    env.close()


@pytest.mark.slow
def test_a_model_set_in_memory_is_recorded_by_its_content_in_the_cache(
    models_file, tmp_path, monkeypatch
):
    monkeypatch.setenv("SCORBOT_GYM_CACHE", str(tmp_path / "cache"))
    models = _loaded(models_file)  # as train_models returns it: no file known
    env = make_env(pose="manifold", pose_kwargs={"models": models}, objects=OBJECTS)
    content = tmp_path.joinpath("cache", *CONTENT_FOLDER)
    assert not content.exists()  # written when the spec is first asked for, not before
    recorded = Path(env.spec.additional_wrappers[-1].kwargs["models"])
    assert recorded.parent == content and recorded.name == f"{content_digest(models)}.npz"
    again = gym.make(env.spec)
    assert again.unwrapped.spec == env.unwrapped.spec
    assert content_digest(again.get_wrapper_attr("source").models) == recorded.stem
    twin = _loaded(models_file)
    other = make_env(pose="manifold", pose_kwargs={"models": twin}, objects=OBJECTS)
    assert other.spec.additional_wrappers[-1].kwargs["models"] == str(recorded)
    assert sorted(content.iterdir()) == [recorded]  # the same content: no second copy
    other.close()
    again.close()
    check_env(env, skip_render_check=True)  # the case: it failed on the missing models
    env.close()


def test_the_default_models_are_named_by_their_cache_file(models_file, tmp_path, monkeypatch):
    from scorbot_gym.perception import training
    from scorbot_gym.perception.references import default_models

    cache = tmp_path / "cache"
    path = training.default_models_path("top", 320, 240, OBJECTS, cache_dir=cache)
    path.parent.mkdir(parents=True)
    path.write_bytes(models_file.read_bytes())
    monkeypatch.setattr(training, "default_pose_models", lambda *a, **k: _loaded(path))
    models = default_models("top", 320, 240, objects=OBJECTS, cache_dir=cache)
    env = make_env(pose="manifold", pose_kwargs={"models": models}, objects=OBJECTS)
    assert env.spec.additional_wrappers[-1].kwargs["models"] == str(path.resolve())
    env.close()
    # a set that is not that file's (the header's objects differ) is not named by it
    monkeypatch.setenv("SCORBOT_GYM_CACHE", str(cache))
    one = _loaded(models_file)
    one.estimators.pop("box")
    monkeypatch.setattr(training, "default_pose_models", lambda *a, **k: one)
    other = default_models("top", 320, 240, objects=OBJECTS, cache_dir=cache)
    env = make_env(pose="manifold", pose_kwargs={"models": other}, objects=["tomato_soup_can"])
    assert Path(env.spec.additional_wrappers[-1].kwargs["models"]).parent.name == "content"
    env.close()


def test_an_overwritten_model_file_is_not_what_the_spec_names(models_file, tmp_path, monkeypatch):
    monkeypatch.setenv("SCORBOT_GYM_CACHE", str(tmp_path / "cache"))
    copy = tmp_path / "mine.npz"
    copy.write_bytes(models_file.read_bytes())
    models = load_model_set(copy)
    assert make_env(pose="manifold", pose_kwargs={"models": models}, objects=OBJECTS).spec
    copy.write_bytes(b"something else now")
    os.utime(copy, ns=(1, 1))
    env = make_env(pose="manifold", pose_kwargs={"models": models}, objects=OBJECTS)
    recorded = Path(env.spec.additional_wrappers[-1].kwargs["models"])
    assert recorded != copy and recorded.stem == content_digest(models)
    env.close()


def test_a_source_that_cannot_be_recorded_refuses_to_be_remade_in_one_line(models_file):
    by_hand = PoseEstimateObservation(gym.make("ScorbotGrasp-v0", object_name="box"),
                                      OraclePoseSource())  # fmt: skip
    with pytest.raises(ValueError, match="cannot rebuild its pose source: it is a OraclePose") as e:
        gym.make(by_hand.spec)
    assert "\n" not in str(e.value)
    by_hand.close()

    class Segmenter:  # a component object: the spec cannot hold it
        pass

    from scorbot_gym.perception.registry import make_pose_source

    source = make_pose_source("oracle")
    source.made_from = ("manifold", {"models": str(models_file), "segmenter": Segmenter()})
    env = PoseEstimateObservation(gym.make("ScorbotGrasp-v0", object_name="box"), source)
    with pytest.raises(ValueError, match=r"'manifold' was made with objects as segmenter \(Seg"):
        gym.make(env.spec)
    env.close()


@pytest.mark.slow
@pytest.mark.parametrize(
    "variant",
    [
        {"segmenter": "privileged"},
        {"motion": "silhouette", "support": "none"},
        {"recognizer": "flr", "cameras": ["top", "side"]},
        "chance",
    ],
    ids=["privileged", "motion-no-support", "flr-two-cameras", "chance-arm"],
)
def test_the_manifold_sources_settings_are_rebuilt_too(variant, models_file):
    models = load_model_set(models_file)
    if variant == "chance":  # the image-blind arm: a baseline's set, the trained recognition
        from scorbot_gym.perception.baseline_models import baseline_source_kwargs

        variant = baseline_source_kwargs("chance", models, "appearance", ["top"])
    env = make_env(pose="manifold", pose_kwargs={"models": models, **variant}, objects=OBJECTS,
                   identity="recognize")  # fmt: skip
    recorded = env.spec.additional_wrappers[-1].kwargs
    assert "source_not_recorded" not in recorded
    assert all(isinstance(v, (str, int, float, bool, list, tuple, type(None)))
               for v in recorded.values())  # fmt: skip
    again = gym.make(env.spec)
    a, b = env.reset(seed=1)[1]["perception"], again.reset(seed=1)[1]["perception"]
    assert a == b and a["recognised"] is not None
    again.close()
    check_env(env, skip_render_check=True)
    env.close()


# --- the command line: the main job reads no ground truth, clutter gets the clutter pipeline --
def _rollout_config(*argv: str):
    from scorbot_gym.cli import build_parser
    from scorbot_gym.cli.rollout import config_from_args

    return config_from_args(build_parser().parse_args(["rollout", *argv]))


def test_rollout_pose_manifold_recognises_by_default():
    config = _rollout_config("--pose", "manifold")
    assert config.recognize and config.pose_cameras == ("top", "side")
    assert _rollout_config("--pose", "manifold", "--recognize").recognize
    assert _rollout_config("--pose", "manifold", "--identity", "recognize").recognize
    given = _rollout_config("--pose", "manifold", "--identity", "given")
    assert not given.recognize and given.pose_cameras == ("top",)


def test_the_privileged_identity_is_labelled_in_the_summary():
    from scorbot_gym.evaluation import format_summary
    from scorbot_gym.evaluation.rollout import RolloutConfig, rollout_summary

    given = RolloutConfig(pose="manifold", recognize=False)
    recognised = RolloutConfig(pose="manifold", recognize=True)
    rows = format_summary(rollout_summary(given, [])).splitlines()
    assert "identity given: privileged, the estimator is told the true class" in [
        " ".join(row.split()) for row in rows
    ]
    assert "privileged" not in format_summary(rollout_summary(recognised, []))


@pytest.mark.parametrize(
    "argv", [(), ("--recognize",), ("--identity", "recognize")], ids=["plain", "recognize", "id"]
)
def test_rollout_pose_manifold_with_distractors_runs_the_clutter_pipeline(argv):
    config = _rollout_config("--pose", "manifold", "--distractors", "2", *argv)
    assert config.pose == "manifold_clutter" and not config.recognize
    assert config.pose_cameras == ("top",)


def test_the_cli_says_which_pipeline_runs(monkeypatch, capsys):
    import scorbot_gym.evaluation.rollout as rollout
    from scorbot_gym.cli import main

    def stop(configs, jobs=1, progress=False, ray=None):
        raise ValueError(f"stopped before any episode, pose {configs[0].pose}")

    monkeypatch.setattr(rollout, "run_rollouts", stop)
    assert main(["rollout", "--pose", "manifold", "--distractors", "2"]) == 2
    out, err = capsys.readouterr()
    assert out.strip() == (
        "--pose manifold with --distractors 2: the clutter pipeline (--pose manifold_clutter: "
        "blobs split, each recognised, the target's pose estimated)"
    )
    assert "pose manifold_clutter" in err


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--pose", "manifold", "--recognize", "--identity", "given"], "contradict each other"),
        (
            ["--pose", "manifold", "--identity", "given", "--distractors", "2"],
            "--identity given does not apply with --distractors",
        ),
        (["--pose", "oracle", "--identity", "given"], "--identity applies to --pose manifold, n"),
        (
            ["--pose", "manifold_clutter", "--identity", "recognize", "--distractors", "1"],
            "--identity applies to --pose manifold, not manifold_clutter",
        ),
        (
            ["--pose", "manifold", "--distractors", "2", "--motion", "silhouette"],
            "runs the clutter pipeline 'manifold_clutter', which has no motion: drop them",
        ),
        (
            [
                "--pose",
                "manifold",
                "--distractors",
                "1",
                "--pose-camera",
                "top",
                "--pose-camera",
                "side",
            ],
            "which has no pose_cameras (one camera)",
        ),
        (
            ["--pose", "manifold", "--distractors", "1", "--segmenter", "privileged"],
            "which has no segmenter",
        ),
    ],  # fmt: skip
)
def test_contradicting_identity_or_clutter_options_are_one_line_errors(argv, message, capsys):
    from scorbot_gym.cli import main

    assert main(["rollout", *argv, "--episodes", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and message in err
