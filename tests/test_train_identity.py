"""``scorbot-gym train --pose manifold`` recognises the object by default, as ``rollout --pose
manifold`` does (issue 50: the main job needs no flag to be free of privileged input); the
estimator is told the true class only with ``--identity given``, which the run records in
``config.json`` and ``policy.json``; runs from before the option resume with what they trained
with (the class given)."""

from __future__ import annotations

import json

import pytest

from scorbot_gym.cli import build_parser, main
from scorbot_gym.cli.train import config_from_args
from scorbot_gym.rl.training import TrainConfig, make_policy_env, train

pytestmark = pytest.mark.rl


@pytest.fixture(scope="module")
def box_models(tmp_path_factory) -> str:
    """Pose models of the box alone (few views, top camera 320 x 240): a stand-in for the
    default models, which take minutes to train on a cold cache."""
    from scorbot_gym.perception.training import train_models

    path = tmp_path_factory.mktemp("models") / "box.npz"
    train_models(["box"], n_views=36, progress=False)[0].save(path)
    return str(path)


def manifold(models: str, **kw) -> TrainConfig:
    return TrainConfig(pose="manifold", pose_model=models, objects=["box"], **kw)


def test_a_manifold_run_recognises_unless_it_opts_into_the_given_identity(box_models):
    default = manifold(box_models).validate().resolved()
    assert default.identity == "recognize", "config.json records what the run observed"
    given = manifold(box_models, identity="given").validate().resolved()
    assert given.identity == "given"
    assert TrainConfig().validate().resolved().identity is None  # the oracle reads the truth
    cases = ((default, "recognize", ["top", "side"]), (given, "given", None))
    for config, identity, cameras in cases:
        env = make_policy_env(config)
        try:
            _, info = env.reset(seed=0)
            assert info["perception"]["identity"] == identity
            assert info["perception"]["privileged"] is False
            assert (info["perception"]["recognised"] is not None) == (identity == "recognize")
            kwargs = env.spec.additional_wrappers[-1].kwargs
            assert kwargs["identity"] == identity and kwargs.get("cameras") == cameras
        finally:
            env.close()


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"identity": "given"}, "identity only applies to pose 'manifold', not 'oracle'"),
        ({"pose": "noisy", "identity": "recognize"}, "identity only applies to pose 'manifold'"),
        ({"pose": "manifold", "identity": "told"}, "identity must be one of"),
        ({"pose": "manifold", "identity": 1}, "identity must be one of"),
    ],
)
def test_bad_identities_are_one_line_errors(kwargs, message):
    with pytest.raises(ValueError, match=message) as err:
        TrainConfig(**kwargs).validate()
    assert len(str(err.value).splitlines()) == 1


def test_runs_from_before_the_option_keep_the_identity_they_trained_with():
    old = TrainConfig(pose="manifold").to_json()
    del old["identity"]
    assert TrainConfig.from_json(old).identity == "given"
    old_oracle = TrainConfig().to_json()
    del old_oracle["identity"]
    assert TrainConfig.from_json(old_oracle).identity is None
    assert TrainConfig.as_older_runs_meant(old)["identity"] == "given"  # what resume compares


def test_the_command_line_takes_identity_for_new_manifold_runs_only(tmp_path, capsys):
    parser = build_parser()
    args = parser.parse_args(["train", "--pose", "manifold", "--out", str(tmp_path / "r")])
    assert config_from_args(args).resolved().identity == "recognize"
    argv = ["train", "--pose", "manifold", "--identity", "given", "--out", str(tmp_path / "r")]
    assert config_from_args(parser.parse_args(argv)).identity == "given"
    assert main(["train", "--identity", "given", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "identity only applies to pose 'manifold'" in err and len(err.strip().splitlines()) == 1
    assert main(["train", "--resume", str(tmp_path), "--identity", "given"]) == 2
    assert "--identity cannot change" in capsys.readouterr().err


@pytest.mark.slow
def test_a_run_records_its_identity_in_config_and_policy_json(box_models, tmp_path):
    out = tmp_path / "run"
    config = manifold(
        box_models,
        timesteps=8,
        hyperparams={"learning_starts": 100, "buffer_size": 100, "net_arch": [8]},
        eval_every=8,
        eval_episodes=1,
        checkpoint_every=8,
        progress_bar=False,
        tensorboard=False,
    )
    train(config, out)
    assert json.loads((out / "config.json").read_text())["identity"] == "recognize"
    meta = json.loads((out / "policy" / "policy.json").read_text())
    assert meta["config"]["identity"] == "recognize"
    assert meta["provenance"]["data"]["identity"] == "recognize"


@pytest.mark.slow
def test_demonstrations_on_the_manifold_pose_recognise_and_record_it(
    box_models, tmp_path, monkeypatch
):
    """``scorbot-gym demos --pose manifold`` (the imitation trainer's datasets) recognises the
    object by default too, and the dataset's settings say so."""
    import minari

    from scorbot_gym.rl.datasets import read_dataset, record_demonstrations

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    record_demonstrations(
        "scorbot/identity-test-v0",
        episodes=1,
        pose="manifold",
        pose_kwargs={"models": box_models},
        objects=["box"],
    )
    assert read_dataset("scorbot/identity-test-v0").settings["identity"] == "recognize"
    spec = minari.load_dataset("scorbot/identity-test-v0").env_spec
    assert spec.additional_wrappers[-1].kwargs["identity"] == "recognize"  # what the env did
    with pytest.raises(ValueError, match="identity only applies to pose 'manifold'"):
        record_demonstrations("scorbot/identity-oracle-v0", episodes=1, identity="given")
    with pytest.raises(ValueError, match="identity must be one of"):
        record_demonstrations("scorbot/identity-bad-v0", 1, pose="manifold", identity="told")
