"""The image-blind ``chance`` pose condition of ``scorbot-gym compare`` (issue 36, the project's
rule: the chance level beside every estimator figure): the ``manifold`` condition with the
estimator swapped for a constant rotation fitted on the default models' views, the same
recognition without the trained models' pose estimates, and its fitted set cached."""

from __future__ import annotations

import dataclasses
import os

import numpy as np
import pytest

from pose.baselines import ChanceEstimator
from pose.model_set import PoseModelSet
from pose.recognition import AppearanceRecognizer
from scorbot_gym.cli import main
from scorbot_gym.evaluation import compare as cmp
from scorbot_gym.perception.base import PerceptionFrame
from scorbot_gym.perception.baseline_models import baseline_models, baseline_models_path
from scorbot_gym.perception.model_set import ModelSetPoseSource
from scorbot_gym.perception.recognizers import IdentityOnlyRecognizer
from scorbot_gym.perception.training import TrainingSet, train_models

#: a coarse training grid (a heading every 60 degrees): pose models of two objects in seconds
COARSE = TrainingSet(yaw_step_deg=60.0)
OBJECTS = ["box", "potted_meat_can"]


@pytest.fixture(scope="module")
def two_models() -> PoseModelSet:
    """Real pose-manifold models of two objects (so that recognition has something to decide),
    trained on COARSE's views in the default render cache."""
    models, _ = train_models(OBJECTS, training=COARSE, progress=False)
    return models


@pytest.fixture()
def default_models(monkeypatch, two_models) -> list:
    """``default_pose_models`` (what the estimator conditions run) answering ``two_models``,
    counting its calls."""
    import scorbot_gym.perception.training as training

    calls = []

    def default_pose_models(*args, **kwargs):
        calls.append(kwargs)
        return two_models

    monkeypatch.setattr(training, "default_pose_models", default_pose_models)
    return calls


def test_chance_is_the_manifold_condition_with_only_the_estimator_named_apart(tmp_path):
    manifold, chance = cmp.pose_conditions(["manifold", "chance"])
    assert chance.source == manifold.source == "manifold"
    assert chance.kwargs == manifold.kwargs  # same masks, cameras and recogniser
    assert chance.identity == manifold.identity == "recognize"  # no privileged input
    assert chance.noise_m is None and chance.noise_yaw_deg is None  # not a noise level
    assert chance.record() == {**manifold.record(), "label": "chance", "estimator": "chance"}
    assert manifold.record()["estimator"] == "manifold"
    assert cmp.pose_conditions(["oracle"])[0].record()["estimator"] is None
    # a model file is the manifold condition's; chance stays beside the default models
    manifold, chance = cmp.pose_conditions(["manifold", "chance"], pose_model=tmp_path / "m.npz")
    assert "models" in manifold.kwargs and "models" not in chance.kwargs


def test_an_unknown_pose_condition_names_chance_among_the_valid_ones(capsys):
    valid = r"valid: oracle, noisy, occluded, manifold, chance, occluded@D\[:HIGH\]$"
    with pytest.raises(ValueError, match=valid):
        cmp.pose_conditions(["chancy"])
    assert main(["compare", "--policies", "scripted", "--pose", "chancy", "--episodes", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "'chancy'" in err and "chance" in err


@pytest.mark.slow
def test_chance_runs_the_chance_set_and_the_default_models_recognition(default_models):
    manifold, chance = cmp.with_models(cmp.pose_conditions(["manifold", "chance"]), progress=False)
    assert len(default_models) == 1  # once, for both conditions
    two = manifold.kwargs["models"]
    assert manifold.kwargs["recognizer"] == cmp.MANIFOLD_RECOGNIZER  # built by each source
    blind = chance.kwargs["models"]
    assert blind.object_names == two.object_names
    assert all(isinstance(blind[n], ChanceEstimator) for n in OBJECTS)
    assert blind.meta["views_of"] == COARSE.to_dict()  # the default models' training views
    assert {k: blind.meta[k] for k in ("camera", "width", "height", "seed")} == {
        k: two.meta[k] for k in ("camera", "width", "height", "seed")
    }
    # recognised by the default models, named, so that the env's spec can rebuild the source
    assert chance.kwargs["recognizer"] == cmp.MANIFOLD_RECOGNIZER
    assert chance.kwargs["recognition_models"] is two
    no_images = {"segmenter": "privileged", "calibration": "none"}
    source = ModelSetPoseSource(**{**chance.kwargs, **no_images})
    source.reset(PerceptionFrame(), None)  # no identity: recognition is set up
    rec = source._recognizer
    assert isinstance(rec, IdentityOnlyRecognizer)
    assert isinstance(rec.recognizer, AppearanceRecognizer) and rec.reads == "view"
    assert set(rec.recognizer.estimators) == set(OBJECTS)  # the trained models'
    # the fitted set comes from the cache the second time
    path = baseline_models_path("chance", COARSE, OBJECTS)
    before = path.stat().st_mtime_ns
    cmp.with_models(cmp.pose_conditions(["chance"]), progress=False)
    assert path.stat().st_mtime_ns == before


@pytest.mark.slow
def test_recognition_without_estimates_keeps_the_answer_and_drops_the_poses(two_models):
    from scorbot_gym.data.views import render_views

    pose = COARSE.samples(3, seed=0)[:1]  # a box view the models were trained on (cached)
    view = render_views("box", pose, width=320, height=240, progress=False)[0].view
    view = dataclasses.replace(view, object_name=None)  # the identity withheld
    appearance = AppearanceRecognizer(two_models.estimators)
    full = appearance.recognize(view)
    blind = IdentityOnlyRecognizer(appearance).recognize(view)
    assert full.label == blind.label == "box"
    assert full.estimates and blind.estimates == {}
    assert blind.costs == full.costs and blind.margin == full.margin
    with pytest.raises(TypeError, match="recognize"):
        IdentityOnlyRecognizer(object())


@pytest.mark.slow
def test_the_baseline_set_is_cached_and_an_unreadable_entry_is_refitted(tmp_path):
    first = baseline_models("chance", COARSE, ["box"], progress=False, cache_dir=tmp_path)
    stamp = first.stat().st_mtime_ns
    assert baseline_models("chance", COARSE, ["box"], progress=False, cache_dir=tmp_path) == first
    assert first.stat().st_mtime_ns == stamp  # read, not fitted again
    first.write_bytes(b"not a model set")
    with pytest.warns(UserWarning, match="discarding unreadable cached baseline set"):
        again = baseline_models("chance", COARSE, ["box"], progress=False, cache_dir=tmp_path)
    assert again == first and isinstance(PoseModelSet.load(again)["box"], ChanceEstimator)
    with pytest.raises(ValueError, match="chancy"):
        baseline_models("chancy", COARSE, ["box"], cache_dir=tmp_path)
    assert not any(p.name.endswith(".tmp") for p in tmp_path.rglob("*"))  # atomic writes


@pytest.mark.slow
@pytest.mark.rl
def test_a_compare_run_with_the_chance_condition_writes_the_documented_keys(
    default_models, tmp_path
):
    report = cmp.compare(["scripted"], ["chance"], 1, seed=3, objects=["box"], progress=False)
    assert report["conditions"] == [
        {"label": "chance", "source": "manifold", "noise_pos_m": None, "noise_yaw_deg": None,
         "identity": "recognize", "segmenter": "background", "estimator": "chance"}
    ]  # fmt: skip
    (rec,) = report["results"]
    assert (rec["pose"], rec["pose_source"], rec["episodes"]) == ("chance", "manifold", 1)
    assert rec["noise_pos_m"] is None and len(rec["episode_success"]) == 1
    assert rec["perception"]["estimates"] > 0  # the estimates were made (and scored)
    assert rec["perception"]["recognition_accuracy"] is not None  # among the two objects
    assert report["noise_curves"] == {}  # chance is no noise level
    assert "`chance`" in cmp.markdown_table(report)
    assert cmp.headline(report).startswith("chance, 1 paired episodes")
    assert cmp.plot_comparison(report, tmp_path / "c.png") == ["success", "objects"]
    assert os.path.getsize(tmp_path / "c.png") > 0
    assert np.isfinite(rec["success_rate"])


def _record(policy: str, pose: str, successes: int, n: int) -> dict:
    return {
        "policy": policy, "label": policy, "pose": pose, "episodes": n, "successes": successes,
        "success_rate": successes / n, "ci95": list(cmp.wilson_interval(successes, n)),
        "noise_pos_m": None, "noise_yaw_deg": None,
        "per_object": {"box": {"episodes": n, "successes": successes}},
        "training": {"trained_from": "scripted"}, "vs_reference": None,
    }  # fmt: skip


def test_the_figure_and_headline_put_the_chance_level_beside_the_estimator(tmp_path):
    results = [_record(p, pose, k, 40) for pose, k in (("manifold", 38), ("chance", 2))
               for p in ("scripted", "learned")]  # fmt: skip
    report = {"episodes": 40, "seeds": [0, 39], "reference": "scripted", "results": results}
    report["noise_curves"] = cmp.noise_curves(results)
    assert report["noise_curves"] == {}  # neither estimator condition is a noise level
    head = cmp.headline(report).splitlines()
    assert head[0].startswith("manifold, 40 paired episodes") and len(head) == 4
    assert head[-1] == (
        "chance level (rotation-blind: image position, constant rotation): "
        "scripted 5.0 % (1.4–16.5), learned 5.0 % (1.4–16.5)"
    )
    assert len(cmp.headline(report, pose="chance").splitlines()) == 3  # not beside itself
    assert cmp.plot_comparison(report, tmp_path / "f.png") == ["success", "objects"]


def test_the_readme_tables_do_not_call_the_chance_level_the_estimator():
    import runpy
    from pathlib import Path

    tables = runpy.run_path(
        str(Path(__file__).resolve().parents[1] / "benchmarks" / "tables.py"), run_name="tables"
    )
    manifold, chance = (c.record() for c in cmp.pose_conditions(["manifold", "chance"]))
    assert "pose-manifold estimator" in tables["_condition_words"](manifold)
    words = tables["_condition_words"](chance)
    assert "chance level" in words and "pose-manifold estimator" not in words
    assert "rotation-blind" in words and "image-blind" not in words  # the position is the image's
