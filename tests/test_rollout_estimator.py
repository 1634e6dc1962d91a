"""``RolloutConfig.estimator``: the closed loop's image-blind (or baseline) arm is the
``manifold`` source with only its trained models swapped, so the chance level can stand beside
every closed-loop estimator figure (the project's evaluation rule)."""

from __future__ import annotations

import pytest

from pose.baselines import ChanceEstimator
from pose.model_set import PoseModelSet
from pose.recognition import AppearanceRecognizer
from scorbot_gym.evaluation.rollout import RolloutConfig, run_rollout
from scorbot_gym.perception.model_set import ModelSetPoseSource
from scorbot_gym.perception.recognizers import IdentityOnlyRecognizer
from scorbot_gym.perception.training import TrainingSet, train_models

#: a coarse training grid (a heading every 60 degrees): pose models of two objects in seconds
COARSE = TrainingSet(yaw_step_deg=60.0)
OBJECTS = ("box", "potted_meat_can")


@pytest.fixture(scope="module")
def two_models() -> PoseModelSet:
    models, _ = train_models(list(OBJECTS), training=COARSE, progress=False)
    return models


@pytest.fixture()
def defaults(monkeypatch, two_models) -> PoseModelSet:
    """``default_pose_models`` answering the two-object models."""
    import scorbot_gym.perception.training as training

    monkeypatch.setattr(training, "default_pose_models", lambda *a, **k: two_models)
    return two_models


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"pose": "manifold", "estimator": "chancy"}, "estimator must be 'manifold' or a pose"),
        ({"pose": "oracle", "estimator": "chance"}, "swaps the default models of pose 'manifold'"),
        (
            {"pose": "manifold", "estimator": "chance", "pose_model": "m.npz"},
            "no pose_model",
        ),
        (
            {"pose": "manifold", "estimator": "chance", "fallback_cameras": ("side",)},
            "no fallback_cameras",
        ),
    ],
)
def test_a_bad_estimator_is_a_one_line_error(kwargs, message):
    with pytest.raises(ValueError, match=message) as err:
        RolloutConfig(**kwargs)
    assert "\n" not in str(err.value)


def test_the_default_estimator_keeps_the_trained_models(defaults):
    kw = RolloutConfig(pose="manifold", recognize=True).pose_kwargs()
    assert kw["models"] is defaults and kw["recognizer"] == "appearance"


@pytest.mark.slow
def test_chance_swaps_the_models_and_keeps_recognition_without_its_estimates(defaults):
    manifold = RolloutConfig(pose="manifold", recognize=True).pose_kwargs()
    chance = RolloutConfig(pose="manifold", recognize=True, estimator="chance").pose_kwargs()
    swapped = ("models", "recognizer", "recognition_models")
    assert {k: v for k, v in chance.items() if k not in swapped} == {
        k: v for k, v in manifold.items() if k not in swapped
    }  # same masks, cameras, prior
    blind = chance["models"]
    assert blind.object_names == defaults.object_names
    assert all(isinstance(blind[n], ChanceEstimator) for n in OBJECTS)
    assert blind.meta["views_of"] == COARSE.to_dict()  # fitted on the trained models' views
    # recognition by the trained models, named (so the env's spec can rebuild the source)
    assert chance["recognizer"] == "appearance" and chance["recognition_models"] is defaults
    source = ModelSetPoseSource(**{**chance, "segmenter": "privileged", "calibration": "none"})
    source.reset(_frame_without_identity(), None)
    rec = source._recognizer
    assert isinstance(rec, IdentityOnlyRecognizer)
    assert isinstance(rec.recognizer, AppearanceRecognizer)
    assert set(rec.recognizer.estimators) == set(OBJECTS)  # the trained models'
    # the identity given: nothing to recognise, the recogniser stays the manifold arm's name
    given = RolloutConfig(pose="manifold", estimator="chance").pose_kwargs()
    assert given["recognizer"] == "appearance" and "recognition_models" not in given
    assert isinstance(given["models"]["box"], ChanceEstimator)


def _frame_without_identity():
    """A reset's frame whose object the source must recognise."""
    from scorbot_gym.perception.base import PerceptionFrame

    return PerceptionFrame(observation={}, cameras={}, object_name=None)


@pytest.mark.slow
def test_a_chance_episode_runs_and_records_its_estimator(defaults):
    config = RolloutConfig(pose="manifold", estimator="chance", objects=OBJECTS, episodes=1, seed=3)
    summary, _ = run_rollout(config, progress=False)
    assert summary["episodes"] == 1 and summary["config"]["estimator"] == "chance"


def test_the_cli_names_a_bad_estimator_in_one_line(capsys):
    from scorbot_gym.cli import main

    assert main(["rollout", "--pose", "oracle", "--estimator", "chance", "--episodes", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "estimator 'chance'" in err
    assert main(["rollout", "--pose", "manifold", "--estimator", "chancy", "--episodes", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "'chancy'" in err
