"""RL-Zoo habits of ``scorbot-gym train`` (#49 item 7): a user hyperparameter file
(``--conf FILE.yml``) recorded in the run, ``evaluations.npz`` beside the Monitor CSVs in the
format of SB3's ``EvalCallback``, a Monitor log whose episodes SB3's ``load_results`` orders
right after ``--resume``; and the provenance of the policies such a run exports (#49 item 6).

Small runs: SAC, oracle pose, one object, a few hundred env steps.
"""

from __future__ import annotations

import json
import shutil
import sys

import numpy as np
import pytest
import yaml

from scorbot_gym import seeds
from scorbot_gym.cli import main
from scorbot_gym.rl import runs
from scorbot_gym.rl.training import EVAL_SEED, resume

pytestmark = pytest.mark.rl

TINY = [
    "--algo", "sac", "--objects", "box", "--timesteps", "160", "--eval-every", "80",
    "--eval-episodes", "2", "--checkpoint-every", "80", "--no-progress", "--no-tensorboard",
]  # fmt: skip
CONF = """\
# my SAC settings (the schema of the package's hyperparams/sac.yml)
default:
  gamma: 0.95
  batch_size: 32
  buffer_size: 500
  learning_starts: 40
  net_arch: [16, 16]
residual:
  gamma: 0.5
"""


@pytest.fixture(scope="module")
def conf_run(tmp_path_factory):
    """``scorbot-gym train --conf my.yml --hyperparams gamma=0.9``: 160 steps."""
    tmp = tmp_path_factory.mktemp("conf")
    conf = tmp / "my.yml"
    conf.write_text(CONF)
    out = tmp / "run"
    argv = ["train", *TINY, "--conf", str(conf), "--hyperparams", "tau=0.02", "gamma=0.9"]
    assert main([*argv, "--out", str(out)]) == 0
    return out, conf


def test_conf_file_sets_the_runs_hyperparameters_and_is_recorded(conf_run):
    out, conf = conf_run
    hp = json.loads((out / runs.CONFIG).read_text())["hyperparams"]
    # from the file, except gamma (--hyperparams wins); tau from --hyperparams; the rest shipped
    assert (hp["batch_size"], hp["buffer_size"], hp["learning_starts"]) == (32, 500, 40)
    assert hp["net_arch"] == [16, 16] and hp["gamma"] == 0.9 and hp["tau"] == 0.02
    assert hp["train_freq"] == 1, "keys the file does not name come from hyperparams/sac.yml"
    assert (out / runs.CONF).read_text() == CONF, "the file is copied as given"
    record = yaml.safe_load((out / runs.HYPERPARAMS).read_text())
    assert record["conf"]["file"] == str(conf) and record["conf"]["entry"] == "default"
    assert record["conf"]["overridden_by_hyperparams"] == {"gamma": 0.9}
    import hashlib

    assert record["conf"]["sha256"] == hashlib.sha256(CONF.encode()).hexdigest()


@pytest.mark.parametrize(
    "text, message",
    [
        ("default: [1, 2\n", "not valid YAML at line"),
        ("- gamma: 0.9\n", "must map setting names"),
        ("residual:\n  gamma: 0.9\n", "has no entry 'default'"),
        ("default:\n  gama: 0.9\n", "unknown hyperparameter 'gama'"),
        ("default:\n  gamma: 2\n", "gamma must be a number in (0.0, 1.0]"),
        ("default:\n  demo_ratio: 0.5\n", "applies only to fine-tuning"),
        ("default: !!python/object/apply:os.system ['true']\n", "not valid YAML"),
    ],
)
def test_bad_conf_files_are_one_line_errors_before_anything_is_written(
    text, message, tmp_path, capsys
):
    conf = tmp_path / "bad.yml"
    conf.write_text(text)
    out = tmp_path / "run"
    assert main(["train", *TINY, "--conf", str(conf), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err and str(conf) in err, err
    assert not out.exists()


def test_conf_is_refused_with_resume_and_a_missing_file_while_parsing(conf_run, capsys):
    out, conf = conf_run
    assert main(["train", "--resume", str(out), "--conf", str(conf)]) == 2
    assert "--conf cannot change" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main(["train", "--conf", str(out / "none.yml"), "--out", str(out / "x")])
    assert exc.value.code == 2 and "no such file" in capsys.readouterr().err


def test_evaluations_npz_is_what_sb3s_eval_callback_writes(conf_run):
    out, _ = conf_run
    state = json.loads((out / runs.CHECKPOINT / runs.STATE).read_text())
    with np.load(out / runs.MONITOR / runs.EVALUATIONS) as npz:
        assert set(npz.files) == {"timesteps", "results", "ep_lengths", "successes"}
        assert npz["timesteps"].tolist() == [e["timesteps"] for e in state["eval"]] == [0, 80, 160]
        assert npz["results"].shape == npz["ep_lengths"].shape == npz["successes"].shape == (3, 2)
        assert npz["ep_lengths"].dtype.kind == "i" and npz["successes"].dtype == bool
        for row, rec in zip(npz["successes"], state["eval"], strict=True):
            assert row.mean() == rec["success_rate"]
        assert (npz["ep_lengths"] >= 1).all() and (npz["ep_lengths"] <= 150).all()
    for rec in state["eval"]:  # where failed episodes ended: the stall diagnostic
        failed = rec["episodes"] - round(rec["success_rate"] * rec["episodes"])
        final = rec["failed_median_final_grasp_distance_m"]
        closest = rec["failed_median_closest_grasp_distance_m"]
        assert (final is None) == (closest is None) == (failed == 0)
        assert final is None or 0 <= closest <= final < 2.0


@pytest.mark.slow
def test_after_resume_monitor_time_is_monotone_and_evaluations_continue(conf_run, tmp_path):
    """SB3's ``load_results`` gives every episode in the order it was played: the resumed
    segment's rows come after the first segment's (a resumed run used to append rows whose
    ``t`` restarted under the first file's header, so they sorted among the first ones)."""
    import time

    from stable_baselines3.common.monitor import load_results

    out = tmp_path / "run"
    shutil.copytree(conf_run[0], out)
    first = load_results(str(out / runs.MONITOR))
    time.sleep(1.0)  # the resumed segment starts later in wall time, as any resume does
    resume(out, timesteps=480)
    both = load_results(str(out / runs.MONITOR))
    assert len(both) > len(first)
    assert both["t"].is_monotonic_increasing
    assert both["t"].iloc[: len(first)].tolist() == first["t"].tolist()
    assert both["t"].iloc[len(first)] > first["t"].iloc[-1] + 0.9
    assert int(both["l"].sum()) <= 480
    with np.load(out / runs.MONITOR / runs.EVALUATIONS) as npz:
        assert npz["timesteps"].tolist() == [0, 80, 160, 240, 320, 400, 480]
        assert npz["results"].shape == (7, 2)


def test_run_policies_say_how_they_were_trained(conf_run, tmp_path):
    out = tmp_path / "run"
    shutil.copytree(conf_run[0], out)
    meta = json.loads((out / runs.POLICY / "policy.json").read_text())
    assert meta["trained_by"] == "rl_from_scratch"
    prov = meta["provenance"]
    assert prov["command"] == sys.argv, "the command as it was run (here: pytest's)"
    assert prov["code"]["version"] == "0.1.0" and prov["code"]["commit"]
    assert prov["pose_models"] is None, "the oracle pose: no pose models"
    first = prov["data"]["training_env_first_resets"]
    assert first["range"] == "training_envs" and first["first"] in seeds.TRAINING_ENVS
    assert prov["data"]["evaluation_seeds"]["first"] == EVAL_SEED
    assert prov["data"]["demonstrations"] is None
    best = json.loads((out / runs.BEST / "policy.json").read_text())
    assert best["provenance"] == prov
    resume(out, timesteps=240)
    resumed = json.loads((out / runs.POLICY / "policy.json").read_text())["provenance"]
    assert resumed["recorded_at"] == prov["recorded_at"], "the first segment's record stays"
    assert len(resumed["resumed"]) == 1 and resumed["resumed"][0]["command"] == sys.argv


def test_training_envs_start_from_their_own_seed_block():
    """SB3 seeds its envs with the model's seed (0, 1, ...: evaluation seeds of ``rollout``);
    the training envs' first resets come from the run's TRAINING_ENVS block instead."""
    from scorbot_gym.rl.training import (
        TrainConfig,
        build_model,
        make_vec_env,
        seed_training_envs,
    )

    config = TrainConfig(objects=["box"], seed=3, n_envs=1, hyperparams={"buffer_size": 100})
    config = config.validate().resolved()
    venv = make_vec_env(config)
    try:
        model = build_model(config, venv, None)
        assert venv.venv._seeds == [3], "SB3's own seeding: an evaluation seed"
        seed_training_envs(model, config)
        assert venv.venv._seeds == [seeds.TRAINING_ENVS.start + 3 * seeds.BLOCK]
        seed_training_envs(model, config, segment=2)
        assert venv.venv._seeds == [seeds.TRAINING_ENVS.start + 3 * seeds.BLOCK + 2]
    finally:
        venv.close()
