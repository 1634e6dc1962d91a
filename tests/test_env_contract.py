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
from scorbot_gym.perception.references import CONTENT_FOLDER
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
    from pose.model_set import PoseModelSet

    return PoseModelSet.load(path)


# Each registered pose source, as make_env builds it: its keywords (a model set object where
# one is needed) and the table it needs (the clutter sources: a target among distractors).
def _env_kwargs(source: str, models_file: Path) -> dict:
    if source == "oracle":
        return {"object_name": "box", "cameras": ["top"], **SMALL}
    if source == "noisy_oracle":
        noise = {"pos_sigma_m": 0.02, "yaw_sigma_deg": 7.0, "dropout": 0.1}
        return {"pose_kwargs": noise, "objects": OBJECTS, "distractors": 1}
    models = {"models": _loaded(models_file)}
    if source == "manifold":
        return {"pose_kwargs": {**models, "recognizer": "appearance"}, "objects": OBJECTS,
                "identity": "recognize", "pose_cameras": ["top"]}  # fmt: skip
    return {"pose_kwargs": models, "objects": OBJECTS, "distractors": 1}


def test_every_registered_pose_source_is_covered():
    """A pose source added to the registry must be added here (and so to the contract)."""
    assert set(pose_source_names()) == {
        "oracle", "noisy_oracle", "manifold", "manifold_clutter", "largest_blob", "random_blob",
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
    env = make_env(pose="manifold", pose_kwargs={"models": _loaded(models_file)}, objects=OBJECTS)
    spec = gym.envs.registration.EnvSpec.from_json(env.spec.to_json())
    assert spec.additional_wrappers[-1].kwargs["models"] == str(models_file.resolve())
    again = gym.make(spec)
    assert again.observation_space == env.observation_space
    again.close()
    env.close()


def test_a_model_set_in_memory_is_recorded_by_its_content_in_the_cache(
    models_file, tmp_path, monkeypatch
):
    monkeypatch.setenv("SCORBOT_GYM_CACHE", str(tmp_path / "cache"))
    models = _loaded(models_file)
    models.path = None  # as train_models returns it: never saved
    env = make_env(pose="manifold", pose_kwargs={"models": models}, objects=OBJECTS)
    recorded = Path(env.spec.additional_wrappers[-1].kwargs["models"])
    content = tmp_path.joinpath("cache", *CONTENT_FOLDER)
    assert recorded.parent == content and recorded.name == f"{models.content_digest()}.npz"
    again = gym.make(env.spec)
    assert again.unwrapped.spec == env.unwrapped.spec
    assert again.get_wrapper_attr("source").models.content_digest() == recorded.stem
    twin = _loaded(models_file)
    twin.path = None
    make_env(pose="manifold", pose_kwargs={"models": twin}, objects=OBJECTS).close()
    assert sorted(content.iterdir()) == [recorded]  # the same content: no second copy
    for e in (again, env):
        e.close()


def test_an_overwritten_model_file_is_not_what_the_spec_names(models_file, tmp_path, monkeypatch):
    monkeypatch.setenv("SCORBOT_GYM_CACHE", str(tmp_path / "cache"))
    copy = tmp_path / "mine.npz"
    copy.write_bytes(models_file.read_bytes())
    models = _loaded(copy)
    copy.write_bytes(b"something else now")
    os.utime(copy, ns=(1, 1))
    env = make_env(pose="manifold", pose_kwargs={"models": models}, objects=OBJECTS)
    recorded = Path(env.spec.additional_wrappers[-1].kwargs["models"])
    assert recorded != copy and recorded.stem == models.content_digest()
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
