"""The RL-Zoo-grade training workflow (#36 item 4) and the train/resume contract under abuse
(#35 items 11 and 12): YAML hyperparameters and overrides recorded in the run folder, Monitor
CSVs (episodes are 150 steps: the runs are a little longer), every evaluation in TensorBoard,
several seeds, replaying a run, learning curves, updates per env step independent of
``n_envs``, and one-line errors for bad options and damaged files.
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import yaml

from scorbot_gym.cli import main
from scorbot_gym.policies.sb3 import SB3Policy
from scorbot_gym.rl import hyperparams as hparams
from scorbot_gym.rl.curves import learning_curves, plot_learning_curves
from scorbot_gym.rl.training import TrainConfig, build_model, make_vec_env, resume, train

pytestmark = pytest.mark.rl

TINY_HP = ["gamma=0.97", "tau=0.02", "batch_size=32", "buffer_size=500", "net_arch=[16,16]"]
TINY = [
    "--algo", "sac", "--objects", "box", "--timesteps", "160", "--learning-starts", "60",
    "--eval-every", "80", "--eval-episodes", "1", "--checkpoint-every", "80", "--no-progress",
]  # fmt: skip


def tiny(**kw) -> TrainConfig:
    base = dict(
        objects=["box"],
        timesteps=60,
        hyperparams={"learning_starts": 30, "batch_size": 32, "buffer_size": 500},
        eval_every=60,
        eval_episodes=1,
        checkpoint_every=60,
        progress_bar=False,
    )
    return TrainConfig(**{**base, **kw})


@pytest.fixture(scope="session")
def two_seeds(tmp_path_factory):
    """``scorbot-gym train --seeds 0,1`` with hyperparameter overrides."""
    out = tmp_path_factory.mktemp("workflow") / "runs"
    assert (
        main(["train", *TINY, "--seeds", "0,1", "--out", str(out), "--hyperparams", *TINY_HP]) == 0
    )
    return out


@pytest.fixture(scope="session")
def one_run(two_seeds):
    return two_seeds / "seed_0"


# --- #36 item 4: the workflow ------------------------------------------------------------------
@pytest.mark.slow
def test_seeds_give_one_run_each_with_the_overrides_recorded(two_seeds):
    assert sorted(p.name for p in two_seeds.iterdir()) == [
        ".scorbot-gym-run.json",  # the marker: a run of this tool
        ".scorbot-gym-run.lock",
        "seed_0",
        "seed_1",
        "seeds.json",
    ]
    for seed in (0, 1):
        run = two_seeds / f"seed_{seed}"
        config = json.loads((run / "config.json").read_text())
        assert config["seed"] == seed
        hp = config["hyperparams"]
        assert (hp["gamma"], hp["tau"], hp["net_arch"], hp["learning_starts"]) == (
            0.97,
            0.02,
            [16, 16],
            60,
        )
        assert hp["train_freq"] == 1, "keys not overridden come from hyperparams/sac.yml"
        record = yaml.safe_load((run / "hyperparams.yml").read_text())
        assert record["hyperparams"] == hp and record["setting"] == "default"
        assert record["sb3"]["updates_per_env_step"] == 1.0
        state = json.loads((run / "checkpoint" / "state.json").read_text())
        assert [e["timesteps"] for e in state["eval"]] == [0, 80, 160]
        model = SB3Policy.load(run / "policy").model
        assert (model.gamma, model.tau) == (0.97, 0.02)
    a, b = (SB3Policy.load(two_seeds / f"seed_{s}" / "policy").model for s in (0, 1))
    pa, pb = (
        np.concatenate([p.detach().numpy().ravel() for p in m.actor.parameters()]) for m in (a, b)
    )
    assert not np.array_equal(pa, pb), "the two seeds trained differently"


@pytest.mark.slow
def test_resuming_a_seeds_folder_continues_every_seed(two_seeds, tmp_path, capsys):
    out = tmp_path / "runs"
    shutil.copytree(two_seeds, out)
    shutil.rmtree(out / "seed_1")  # killed before the second seed started
    argv = ["train", "--resume", str(out), "--timesteps", "240", "--no-progress"]
    assert main(argv) == 0
    assert capsys.readouterr().out.count("240 env steps") == 2
    for seed in (0, 1):
        state = json.loads((out / f"seed_{seed}" / "checkpoint" / "state.json").read_text())
        assert state["timesteps"] == 240 and state["config"]["seed"] == seed


@pytest.mark.slow
def test_monitor_csvs_and_every_evaluation_in_tensorboard(one_run):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    lines = (one_run / "monitor" / "env_0.monitor.csv").read_text().splitlines()
    assert lines[0].startswith("#") and lines[1] == "r,l,t,is_success"
    assert len(lines) >= 3, "at least one finished training episode"
    state = json.loads((one_run / "checkpoint" / "state.json").read_text())
    steps = []
    for events in sorted((one_run / "tb").rglob("events.out.tfevents.*")):
        acc = EventAccumulator(str(events)).Reload()
        if "eval/success_rate" in acc.Tags()["scalars"]:
            steps += [e.step for e in acc.Scalars("eval/success_rate")]
    assert steps == [e["timesteps"] for e in state["eval"]], "the last evaluation reached TB too"


@pytest.mark.slow
def test_rollout_replays_a_training_run_with_a_video_of_every_episode(one_run, tmp_path):
    import imageio.v2 as imageio

    assert (one_run / "best" / "policy.json").is_file()
    state = json.loads((one_run / "checkpoint" / "state.json").read_text())
    assert state["best"]["timesteps"] in [e["timesteps"] for e in state["eval"]]
    chosen = json.loads((one_run / "best" / "policy.json").read_text())["checkpoint"]
    assert chosen["kind"] == "best" and chosen["evaluation"] == state["best"]
    assert chosen["evaluation_seeds"]["range"] == "training_evaluation"  # not a reported range
    js, video = tmp_path / "r.json", tmp_path / "r.mp4"
    argv = ["rollout", "--policy", str(one_run), "--episodes", "2", "--objects", "box"]
    assert main([*argv, "--json", str(js), "--video", str(video), "--no-progress"]) == 0
    summary = json.loads(js.read_text())
    assert summary["episodes"] == 2 and summary["action_type"] == "cartesian"
    with imageio.get_reader(str(video), "ffmpeg") as reader:
        frames = reader.count_frames()
    assert frames == sum(r["steps"] + 1 for r in summary["results"]), "both episodes filmed"
    last = ["--checkpoint", "last", "--episodes", "1", "--objects", "box", "--no-progress"]
    assert main(["rollout", "--policy", str(one_run), *last]) == 0
    assert main(["rollout", "--policy", str(one_run.parent), "--episodes", "1"]) == 2  # which seed?


@pytest.mark.slow
def test_learning_curves_over_seeds(two_seeds, tmp_path):
    report = learning_curves({"sac": [two_seeds]})
    arm = report["sac"]
    assert arm["seeds"] == [0, 1]
    by_steps = arm["by_timesteps"]
    assert by_steps["timesteps"] == [0.0, 80.0, 160.0]
    for lo, m, hi in zip(
        by_steps["ci95_low"], by_steps["mean"], by_steps["ci95_high"], strict=True
    ):
        assert 0.0 <= lo <= m <= hi <= 1.0
    assert len(arm["by_wall_s"]["wall_s"]) >= 1
    plot_learning_curves(report, tmp_path / "c.png")
    assert (tmp_path / "c.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.slow
def test_the_learning_curves_benchmark_reads_run_folders(two_seeds, tmp_path, capsys):
    import runpy
    from pathlib import Path

    script = Path(__file__).resolve().parents[1] / "benchmarks" / "learning_curves.py"
    bench = runpy.run_path(str(script), run_name="benchmark_under_test")["main"]
    out = tmp_path / "curves.json"
    assert bench(["--arm", f"sac={two_seeds}", "--out", str(out)]) == 0
    report = json.loads(out.read_text())
    assert report["arms"]["sac"]["seeds"] == [0, 1]
    assert out.with_suffix(".png").is_file()
    with pytest.raises(SystemExit) as exc:
        bench(["--arm", f"sac={tmp_path / 'none'}", "--out", str(tmp_path / "other.json")])
    assert exc.value.code == 2 and "no run folder" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:  # a result that exists is replaced only if asked
        bench(["--arm", f"sac={two_seeds}", "--out", str(out)])
    assert exc.value.code == 2 and "add --overwrite" in capsys.readouterr().err
    assert bench(["--arm", f"sac={two_seeds}", "--out", str(out), "--overwrite"]) == 0


@pytest.mark.slow
def test_updates_per_env_step_do_not_depend_on_n_envs():
    one, two = (tiny(n_envs=n).schedule() for n in (1, 2))
    assert one["updates_per_env_step"] == two["updates_per_env_step"] == 1.0
    assert (one["gradient_steps"], two["gradient_steps"]) == (1, 2)
    cfg = tiny(n_envs=2, normalize=False)
    venv = make_vec_env(cfg)
    try:
        model = build_model(cfg, venv, None)
        model.learn(90)  # 30 random steps, then an update per env step: 2 per vector step
    finally:
        venv.close()
    assert model.num_timesteps == 90 and model._n_updates == 90 - 30
    ppo = [tiny(algo="ppo", n_envs=n, hyperparams={"n_steps": 64}).schedule() for n in (1, 2)]
    assert ppo[0]["updates_per_env_step"] == ppo[1]["updates_per_env_step"]


@pytest.mark.slow
def test_same_seed_same_parameters_after_the_first_updates(tmp_path):
    def actor_after_training(seed: int, name: str) -> np.ndarray:
        train(
            tiny(seed=seed, hyperparams={"learning_starts": 20, "batch_size": 16}), tmp_path / name
        )
        model = SB3Policy.load(tmp_path / name / "policy").model
        return np.concatenate([p.detach().numpy().ravel() for p in model.actor.parameters()])

    a, b = actor_after_training(5, "a"), actor_after_training(5, "b")
    np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (["foo=1"], "unknown hyperparameter 'foo' for sac; valid: actor_learning_rate, batch_size"),
        (["gamma=1.5"], "gamma must be a number in (0.0, 1.0]"),
        (["net_arch=[0]"], "net_arch must be a non-empty list"),
        (["ent_coef=auto_x"], "ent_coef must be"),
        (["gradient_steps=0"], "gradient_steps must be an integer >= 1"),
        (["n_steps=64"], "unknown hyperparameter 'n_steps' for sac"),
    ],
)
def test_bad_hyperparameter_overrides_are_one_line_errors(overrides, message, tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["train", "--out", str(out), "--hyperparams", *overrides]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err, err
    assert not out.exists(), "a refused run writes nothing"


def test_hyperparameter_files_ship_a_valid_entry_per_algorithm_and_setting():
    for algo in hparams.ALGOS:
        for setting in hparams.SETTINGS:
            hp = hparams.load_defaults(algo, setting)
            assert set(hp) <= set(hparams.valid_keys(algo)) and "net_arch" in hp
            assert ("log_std_init" in hp) == (setting == "residual")
    assert hparams.parse_overrides(["learning_rate=1e-3", "net_arch=[8, 8]"]) == {
        "learning_rate": "1e-3",  # YAML 1.1 reads 1e-3 as text; the check converts it
        "net_arch": [8, 8],
    }
    assert hparams.check("sac", {"learning_rate": "1e-3"}) == {"learning_rate": 1e-3}


# --- #35 item 11: bad options ------------------------------------------------------------------
@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--eval-every", "0"], "--eval-every: must be an integer >= 1"),
        (["--eval-every", "-1"], "--eval-every: must be an integer >= 1"),
        (["--checkpoint-every", "0"], "--checkpoint-every: must be an integer >= 1"),
        (["--net-arch", "-4"], "--net-arch: must be an integer >= 1"),
        (["--net-arch", "0"], "--net-arch: must be an integer >= 1"),
        (["--learning-starts", "-1"], "--learning-starts: must be an integer >= 0"),
        (["--bc-steps", "-1"], "--bc-steps: must be an integer >= 0"),
        (["--seeds", "0,0"], "--seeds: must be distinct integers >= 0"),
    ],
)
def test_bad_train_options_are_refused_while_parsing(argv, message, tmp_path, capsys):
    out = tmp_path / "run"
    with pytest.raises(SystemExit) as exc:
        main(["train", "--out", str(out), *argv])
    assert exc.value.code == 2
    assert message in capsys.readouterr().err.strip().splitlines()[-1]
    assert not out.exists()


def test_out_that_is_a_file_and_a_misplaced_pose_model_are_refused(tmp_path, capsys):
    afile = tmp_path / "afile"
    afile.write_bytes(b"x")
    assert main(["train", "--out", str(afile)]) == 2
    assert "is a file, not a folder" in capsys.readouterr().err
    junk = tmp_path / "junk.npz"
    junk.write_bytes(np.random.default_rng(0).bytes(256))
    out = tmp_path / "run"
    assert main(["train", "--out", str(out), "--pose-model", str(junk)]) == 2
    assert "pose_model only applies to pose 'manifold'" in capsys.readouterr().err
    argv = ["train", "--out", str(out), "--pose", "manifold", "--pose-model", str(junk)]
    assert main(argv) == 2
    assert "is not a model file" in capsys.readouterr().err
    assert not out.exists()
    assert main(["train", "--resume", str(tmp_path), "--algo", "ppo"]) == 2
    assert "--algo cannot change" in capsys.readouterr().err


def test_a_run_stopped_before_its_first_checkpoint_starts_afresh(tmp_path, capsys):
    out = tmp_path / "run"
    (out / "tb").mkdir(parents=True)
    (out / "config.json").write_text(json.dumps(tiny().to_json()))  # killed while building
    (out / ".scorbot-gym-run.json").write_text("{}")  # the marker: the run was this tool's
    assert main(["train", "--resume", str(out)]) == 2
    assert "start it again with --out" in capsys.readouterr().err
    state = train(tiny(), out)
    assert state["timesteps"] == 60 and (out / "checkpoint" / "state.json").is_file()
    with pytest.raises(ValueError, match="already holds a run"):
        train(tiny(), out)


# --- #35 item 12: damaged files on --resume ----------------------------------------------------
def _damage(run, name: str) -> None:
    path = run / name
    rng = np.random.default_rng(1)
    if name in ("checkpoint/model.safetensors", "checkpoint/replay_buffer.npz"):
        path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    elif name == "checkpoint/vecnormalize.json":
        path.write_bytes(rng.bytes(512))
    elif name == "checkpoint/state.json":
        state = json.loads(path.read_text())
        path.write_text(json.dumps({**state, "eval": 5}))
    elif name == "config.json:truncated":
        (run / "config.json").write_text((run / "config.json").read_text()[:40])
    else:  # config.json:<key>=<json>
        key, value = name.split(":")[1].split("=")
        config = json.loads((run / "config.json").read_text())
        if key.startswith("hyperparams."):
            config["hyperparams"][key[12:]] = json.loads(value)
        else:
            config[key] = json.loads(value)
        (run / "config.json").write_text(json.dumps(config))


@pytest.mark.parametrize(
    ("damage", "message"),
    [
        ("checkpoint/model.safetensors", "model.safetensors is not a safetensors model file"),
        ("checkpoint/vecnormalize.json", "vecnormalize.json is damaged or not VecNormalize"),
        ("checkpoint/replay_buffer.npz", "replay_buffer.npz is damaged or not a replay buffer"),
        ("checkpoint/state.json", "state.json: 'eval' is missing or of the wrong type (5)"),
        ("config.json:truncated", "config.json is not valid JSON"),
        ('config.json:algo="ppo"', "differs from the checkpoint's configuration in algo"),
        ("config.json:hyperparams.net_arch=[8]", "in hyperparams.net_arch ([16, 16] -> [8])"),
        ('config.json:eval_episodes="many"', "eval_episodes must be an integer"),
    ],
)
@pytest.mark.slow
def test_resume_refuses_damaged_files_naming_them(one_run, tmp_path, damage, message, capsys):
    run = tmp_path / "run"
    shutil.copytree(one_run, run)
    _damage(run, damage)
    assert main(["train", "--resume", str(run), "--timesteps", "240"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err, err
    with pytest.raises(ValueError, match="cannot resume"):
        resume(run, timesteps=240)


@pytest.mark.slow
def test_resume_starts_a_monitor_segment_and_clears_killed_writes(one_run, tmp_path):
    """A resumed run logs to a Monitor file of its own (its own header and t_start), so the
    first segment's file is left as it was and SB3's ``load_results`` orders every episode by
    time (tests/test_rl_zoo_habits.py checks the order)."""
    run = tmp_path / "run"
    shutil.copytree(one_run, run)
    csv = run / "monitor" / "env_0.monitor.csv"
    before = csv.read_text()
    orphan = run / "checkpoint" / ".model.tmp999.zip"  # what a write killed mid-way leaves
    orphan.write_bytes(b"half a zip")
    state = resume(run, timesteps=320)
    assert state["timesteps"] == 320 and [e["timesteps"] for e in state["eval"]][-1] == 320
    assert csv.read_text() == before
    segment = (run / "monitor" / "env_0.resume1.monitor.csv").read_text().splitlines()
    assert segment[0].startswith("#") and segment[1] == "r,l,t,is_success" and len(segment) > 2
    assert not orphan.exists()


@pytest.mark.slow
def test_resume_names_the_settings_an_older_run_lacks(one_run, tmp_path):
    """A run written before a setting existed resumes with today's default for it, and says so
    (that default need not be what the older version did)."""
    run = tmp_path / "run"
    shutil.copytree(one_run, run)
    for name, key in (("config.json", None), ("checkpoint/state.json", "config")):
        data = json.loads((run / name).read_text())
        (data[key] if key else data).pop("init_policy")
        (run / name).write_text(json.dumps(data))
    lacks = r"predates the settings \['init_policy'\].*init_policy=None"
    with pytest.warns(UserWarning, match=lacks):
        state = resume(run, timesteps=320)
    assert state["timesteps"] == 320


@pytest.mark.slow
def test_a_policy_without_its_normalisation_is_refused(one_run, tmp_path):
    policy = tmp_path / "policy"
    shutil.copytree(one_run / "policy", policy)
    assert json.loads((policy / "policy.json").read_text())["normalize"] is True
    (policy / "normalize.npz").unlink()
    with pytest.raises(FileNotFoundError, match="missing normalize.npz"):
        SB3Policy.load(policy)
    (policy / "normalize.npz").write_bytes(b"garbage")
    with pytest.raises(ValueError, match="normalize.npz is damaged"):
        SB3Policy.load(policy)


def test_train_sets_the_noisy_pose_sources_noise(capsys):
    """``--pose noisy --pos-sigma-m --yaw-sigma-deg`` reach the run's config; elsewhere they are
    a one-line error (they would be silently ignored)."""
    from scorbot_gym.cli import build_parser
    from scorbot_gym.cli.train import config_from_args

    argv = ["train", "--pose", "noisy", "--pos-sigma-m", "0.02", "--yaw-sigma-deg", "20"]
    config = config_from_args(build_parser().parse_args(argv))
    assert (config.noise_pos_m, config.noise_yaw_deg) == (0.02, 20.0)
    config = config_from_args(build_parser().parse_args(["train", "--pose", "noisy"]))
    assert (config.noise_pos_m, config.noise_yaw_deg) == (0.01, 5.0)  # TrainConfig's defaults
    assert main(["train", "--yaw-sigma-deg", "20", "--show-hyperparams"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "apply only to --pose noisy" in err, err


def test_train_sets_the_occluded_pose_sources_settings(capsys):
    """``--pose occluded`` takes the noise and ``--hide-distance-m LOW HIGH``; the env it trains
    in loses the object while the hand is near; a range the wrong way round is a one-line
    error before any work, and ``--hide-distance-m`` elsewhere too."""
    from scorbot_gym.cli import build_parser
    from scorbot_gym.cli.train import config_from_args
    from scorbot_gym.rl.training import make_policy_env

    argv = ["train", "--pose", "occluded", "--pos-sigma-m", "0", "--hide-distance-m", "0.1", "0.3"]
    config = config_from_args(build_parser().parse_args(argv))
    assert (config.noise_pos_m, config.hide_low_m, config.hide_high_m) == (0.0, 0.1, 0.3)
    env = make_policy_env(config)
    source = env.get_wrapper_attr("source")
    assert source.hide_distance_m == (0.1, 0.3) and source.pos_sigma_m == 0.0
    env.close()
    for argv, why in (
        (["--pose", "occluded", "--hide-distance-m", "0.3", "0.1"], "hide_low_m"),
        (["--hide-distance-m", "0.1", "0.3"], "applies only to --pose occluded"),
    ):
        assert main(["train", *argv, "--show-hyperparams"]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and why in err, err


# --- a checkpoint written whole: a kill at any moment leaves one complete ---------------------
def _checkpoint(folder, step: int) -> None:
    folder.mkdir(parents=True)
    (folder / "model.safetensors").write_text(f"weights at {step}")
    (folder / "state.json").write_text(json.dumps({"timesteps": step}))


def _kill_during_save(run, at: str) -> None:
    """``run`` (checkpoint at step 100) as a save of step 200 killed at ``at``."""
    from scorbot_gym.rl import runs

    staging = run / runs.STAGING_CHECKPOINT
    if at == "writing the weights":
        staging.mkdir()
        (staging / "model.safetensors").write_text("weights at 2")  # half written, no state
        return
    _checkpoint(staging, 200)
    if at == "before the swap":
        return
    (run / runs.CHECKPOINT).rename(run / runs.PREVIOUS_CHECKPOINT)
    if at == "between the renames":
        return
    staging.rename(run / runs.CHECKPOINT)  # "before removing the previous one"


@pytest.mark.parametrize(
    ("at", "step"),
    [
        ("writing the weights", 100),
        ("before the swap", 200),
        ("between the renames", 200),
        ("before removing the previous one", 200),
    ],
)
def test_a_save_killed_anywhere_leaves_one_complete_checkpoint(tmp_path, at, step):
    from scorbot_gym.rl import runs

    run = tmp_path / "run"
    _checkpoint(run / runs.CHECKPOINT, 100)
    _kill_during_save(run, at)
    assert runs.has_checkpoint(run)
    runs.settle_checkpoint(run)
    assert sorted(p.name for p in run.iterdir()) == [runs.CHECKPOINT]
    ck = run / runs.CHECKPOINT
    assert json.loads((ck / "state.json").read_text())["timesteps"] == step
    assert (ck / "model.safetensors").read_text() == f"weights at {step}"


def test_swap_in_replaces_the_checkpoint_and_leaves_nothing_aside(tmp_path):
    from scorbot_gym.rl import runs

    run = tmp_path / "run"
    _checkpoint(run / runs.STAGING_CHECKPOINT, 100)
    runs.swap_in(run)  # the first checkpoint: nothing to set aside
    _checkpoint(run / runs.STAGING_CHECKPOINT, 200)
    runs.swap_in(run)
    assert sorted(p.name for p in run.iterdir()) == [runs.CHECKPOINT]
    assert json.loads((run / runs.CHECKPOINT / "state.json").read_text())["timesteps"] == 200


@pytest.mark.slow
def test_resume_continues_from_the_checkpoint_a_killed_swap_set_aside(one_run, tmp_path):
    """A save killed between setting the last checkpoint aside and moving the new one in:
    ``--resume`` continues from the one set aside (the unfinished one is discarded), and
    every save leaves one ``checkpoint/`` and no staging folder."""
    from scorbot_gym.rl import runs

    run = tmp_path / "run"
    shutil.copytree(one_run, run)
    before = json.loads((run / runs.CHECKPOINT / runs.STATE).read_text())["timesteps"]
    (run / runs.CHECKPOINT).rename(run / runs.PREVIOUS_CHECKPOINT)
    (run / runs.STAGING_CHECKPOINT).mkdir()
    (run / runs.STAGING_CHECKPOINT / "model.safetensors").write_bytes(b"half a model")
    state = resume(run, timesteps=before + 80)
    assert state["timesteps"] == before + 80
    assert state["eval"][0]["timesteps"] == 0  # the history of the run set aside, continued
    assert not (run / runs.STAGING_CHECKPOINT).exists()
    assert not (run / runs.PREVIOUS_CHECKPOINT).exists()
