"""Learning from scratch (#49 item 2): the shipped ``scratch`` hyperparameter entries, the
reward recorded with every run, the entry selection, and where the networks update."""

from __future__ import annotations

import json

import numpy as np
import pytest

from scorbot_gym.cli import main
from scorbot_gym.rl import hyperparams as hparams
from scorbot_gym.rl.training import TrainConfig, build_model, make_policy_env, make_vec_env

pytestmark = pytest.mark.rl


def test_scratch_entries_are_set_for_learning_not_for_fine_tuning():
    for algo in hparams.ALGOS:
        hp = hparams.load_defaults(algo, "scratch")
        # SAC's the measured recipe (sac.yml: fresh seeds at 160k); TQC and PPO not run with it
        want = ("normalized_pregrasp", 0.8) if algo == "sac" else ("normalized_dense", 0.99)
        assert (hp["reward_type"], hp["gamma"]) == want
        assert hp.get("reward_gamma", 0.99) == want[1]  # the reward built for the discount
        assert hp["net_arch"] == [256, 256]
        if algo in hparams.OFF_POLICY:
            assert hp["buffer_size"] >= 1_000_000  # holds a 1M-step run
            assert hp["learning_starts"] >= 1000
            assert hp["ent_coef"] == "auto_0.001"
            # the learner sees steps of <= 1: w times the scale, w = (1 - reward_gamma) / 2
            built_for = hp.get("reward_gamma", 0.99)
            assert (1 - built_for) / 2 * hp["reward_scale"] == pytest.approx(1.0)
            assert built_for >= hp["gamma"]
        else:
            assert hp["n_steps"] >= 4096
    # every entry the shipped policies and results came from names the old reward
    for algo in hparams.ALGOS:
        for setting in ("default", "residual"):
            assert hparams.load_defaults(algo, setting)["reward_type"] == "dense"
    assert hparams.load_defaults("sac", hparams.FINETUNE)["reward_type"] == "dense"


def test_the_entry_picks_the_reward_of_the_training_and_evaluation_envs():
    config = TrainConfig(objects=["box"], hyperparams_entry="scratch").validate().resolved()
    assert config.hyperparams["reward_type"] == "normalized_pregrasp"
    assert config.setting == "scratch"
    env = make_policy_env(config)
    assert env.unwrapped.reward_type == "normalized_pregrasp"
    env.close()
    assert env.unwrapped.reward_gamma == 0.8  # the reward built for the entry's discount
    assert env.unwrapped.task.shaping_max == pytest.approx(0.1)
    env.close()
    built_for = TrainConfig(objects=["box"], hyperparams_entry="scratch")
    built_for.hyperparams = {"reward_gamma": 0.99}
    env = make_policy_env(built_for.validate().resolved())
    assert env.unwrapped.reward_gamma == 0.99
    assert env.unwrapped.task.shaping_max == pytest.approx(0.005)
    env.close()
    ablation = TrainConfig(hyperparams_entry="scratch", hyperparams={"reward_type": "dense"})
    with pytest.raises(ValueError, match=r"built for 0.99 \(set reward_gamma=0.99\)"):
        ablation.resolved_hyperparams()  # the entry's reward_gamma has nothing to apply to
    ablation.hyperparams["reward_gamma"] = 0.99
    assert ablation.resolved_hyperparams()["reward_type"] == "dense"
    assert TrainConfig().resolved_hyperparams()["reward_type"] == "dense"


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"hyperparams_entry": "nope"}, "has no entry 'nope'"),
        ({"hyperparams_entry": "residual"}, "is for residual runs"),
        ({"residual": True, "hyperparams_entry": "scratch"}, "uses the hyperparams entry"),
        ({"hyperparams": {"reward_type": "shaped"}}, "reward_type must be one of"),
        ({"device": "gpu"}, "device must be"),
    ],
)
def test_bad_entries_rewards_and_devices_are_one_line_errors(kwargs, message):
    with pytest.raises(ValueError, match=message) as err:
        TrainConfig(**kwargs).validate()
    assert len(str(err.value).splitlines()) == 1


def test_a_run_from_before_reward_type_keeps_the_dense_reward():
    """An older run's resolved hyperparameters lack reward_type: it trained with the env's
    reward then, 'dense', whatever today's entries say."""
    old = TrainConfig(hyperparams_entry=None).resolved().to_json()
    del old["hyperparams"]["reward_type"], old["hyperparams_entry"], old["device"]
    config = TrainConfig.from_json(old)
    assert config.hyperparams["reward_type"] == "dense"
    assert config.device == "cpu" and config.hyperparams_entry is None
    # a scratch run from before reward_scale learned at scale 1, whatever the entry says now
    scratch = TrainConfig(hyperparams_entry="scratch").resolved().to_json()
    del scratch["hyperparams"]["reward_scale"]
    assert TrainConfig.from_json(scratch).resolved_hyperparams()["reward_scale"] == 1.0
    assert TrainConfig(hyperparams_entry="scratch").resolved_hyperparams()["reward_scale"] == 10


def test_updates_run_where_the_device_says():
    import torch as th

    want = "cuda" if th.cuda.is_available() else "cpu"
    for device, expected in (("auto", want), ("cpu", "cpu")):
        config = TrainConfig(
            objects=["box"],
            device=device,
            hyperparams={"buffer_size": 100, "net_arch": [8, 8]},
        ).resolved()
        venv = make_vec_env(config)
        try:
            assert build_model(config, venv, None).device.type == expected
        finally:
            venv.close()


def test_train_records_the_entry_and_the_reward(tmp_path):
    out = tmp_path / "run"
    argv = [
        "train", "--hyperparams-entry", "scratch", "--objects", "box", "--timesteps", "40",
        "--learning-starts", "20", "--eval-every", "40", "--eval-episodes", "1",
        "--checkpoint-every", "40", "--no-progress", "--no-tensorboard", "--device", "cpu",
        "--hyperparams", "buffer_size=200", "batch_size=8", "net_arch=[8,8]", "--out", str(out),
    ]  # fmt: skip
    assert main(argv) == 0
    config = json.loads((out / "config.json").read_text())
    assert config["hyperparams_entry"] == "scratch" and config["device"] == "cpu"
    assert config["hyperparams"]["reward_type"] == "normalized_pregrasp"
    assert config["hyperparams"]["gamma"] == 0.8
    policy = json.loads((out / "policy" / "policy.json").read_text())
    assert policy["config"]["hyperparams"]["reward_type"] == "normalized_pregrasp"


def _tiny_scratch_config() -> TrainConfig:
    """The scratch entry on one object, 40 steps, networks of 8: a run of seconds."""
    return TrainConfig(
        objects=["box"],
        timesteps=40,
        hyperparams_entry="scratch",
        hyperparams={"learning_starts": 20, "batch_size": 8, "buffer_size": 200, "net_arch": [8]},
        eval_every=40,
        eval_episodes=1,
        checkpoint_every=40,
        progress_bar=False,
        tensorboard=False,
        device="cpu",
    )


@pytest.mark.slow
def test_seeds_train_in_parallel_processes_and_resume_in_parallel(tmp_path):
    """Two seeds at once (spawned workers), then continued further, two at once again; each
    evaluation records the return, and the curves carry it with the steps to each level."""
    import dataclasses

    from scorbot_gym.rl.curves import learning_curves
    from scorbot_gym.rl.training import resume, train_seeds

    config = _tiny_scratch_config()
    out = tmp_path / "seeds"
    with pytest.raises(ValueError, match="processes must be an integer >= 1"):
        train_seeds(config, out, [0, 1], processes=0)
    states = train_seeds(config, out, [0, 1], processes=2)["seeds"]
    assert sorted(states) == [0, 1] and all(s["timesteps"] == 40 for s in states.values())
    states = resume(out, timesteps=80, processes=2)["seeds"]
    assert all(s["timesteps"] == 80 for s in states.values())
    for seed in (0, 1):
        run = json.loads((out / f"seed_{seed}" / "config.json").read_text())
        assert run == {**dataclasses.asdict(config.resolved()), "seed": seed, "timesteps": 80}
        assert all("mean_return" in e for e in states[seed]["eval"])
    arm = learning_curves({"scratch": [out]})["scratch"]
    assert arm["seeds"] == [0, 1]
    assert arm["return_by_timesteps"]["timesteps"] == [0.0, 40.0, 80.0]
    assert all(0.0 <= r <= 150.0 for r in arm["return_by_timesteps"]["mean"])
    assert arm["first_reached"]["0.5"]["seeds_reached"] in (0, 1, 2)


@pytest.mark.slow
@pytest.mark.ray
def test_seeds_train_and_resume_as_ray_tasks_as_they_do_in_processes(tmp_path):
    """Each seed a task of a local Ray instance, then continued as tasks: a seed's first
    segment evaluates as the same seed trained in this process; a single run refuses --ray
    (it has no seeds to spread)."""
    from scorbot_gym.rl.training import resume, train_seeds

    config = _tiny_scratch_config()
    ray = pytest.importorskip("ray")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)  # one for both calls
    try:
        states = train_seeds(config, tmp_path / "ray", [0, 1], processes=2, ray="local")["seeds"]
        assert sorted(states) == [0, 1] and all(s["timesteps"] == 40 for s in states.values())
        states = resume(tmp_path / "ray", timesteps=80, processes=2, ray="local")["seeds"]
        assert all(s["timesteps"] == 80 for s in states.values())
    finally:
        ray.shutdown()
    here = train_seeds(config, tmp_path / "here", [1])["seeds"][1]  # in this process
    assert [e["mean_return"] for e in states[1]["eval"][:2]] == [
        e["mean_return"] for e in here["eval"]
    ]
    with pytest.raises(ValueError, match="--ray runs the seeds of a --seeds run"):
        resume(tmp_path / "ray" / "seed_0", timesteps=90, ray="local")
    assert main(["train", "--ray", "--out", str(tmp_path / "one")]) == 2


def test_the_learner_sees_the_reward_times_reward_scale():
    """reward_scale multiplies what the learner is given; the env keeps its [0, 1] reward."""
    import numpy as np

    rewards = {}
    for scale in (1, 200):
        config = TrainConfig(
            objects=["box"],
            hyperparams_entry="scratch",
            hyperparams={"reward_scale": scale},
            normalize=False,
        ).resolved()
        venv = make_vec_env(config)
        try:
            venv.seed(3)
            venv.reset()
            steps = [venv.step(np.zeros((1, 6), np.float32))[1][0] for _ in range(3)]
        finally:
            venv.close()
        rewards[scale] = np.array(steps)
    assert (rewards[1] > 0).all() and (rewards[1] <= 0.1).all()  # w at reward_gamma 0.8
    np.testing.assert_allclose(rewards[200], 200 * rewards[1], rtol=1e-6)


@pytest.mark.parametrize("residual", [False, True])
def test_a_grasp_frame_run_trains_exports_and_acts_on_a_new_object(tmp_path, residual):
    """The scratch entry's policy reads the grasp frame (no class): its run records it, the
    exported policy rebuilds the same observation from a plain env and binds to an env of an
    object it never trained on; a residual's scripted base still reads the class, the
    correction the frame."""
    from scorbot_gym import make_env
    from scorbot_gym.policies.sb3 import SB3Policy

    assert hparams.load_defaults("sac", "scratch")["object_features"] == "grasp_frame"
    assert hparams.load_defaults("sac", "default").get("object_features", "class") == "class"
    out = tmp_path / "run"
    kind = ["--residual"] if residual else ["--hyperparams-entry", "scratch"]
    hp = ["buffer_size=200", "batch_size=8", "net_arch=[8,8]"]
    hp += ["object_features=grasp_frame"] if residual else []
    argv = [
        "train", *kind, "--objects", "box", "--timesteps", "40",
        "--learning-starts", "20", "--eval-every", "40", "--eval-episodes", "1",
        "--checkpoint-every", "40", "--no-progress", "--no-tensorboard", "--device", "cpu",
        "--hyperparams", *hp, "--out", str(out),
    ]  # fmt: skip
    assert main(argv) == 0
    policy = SB3Policy.load(out / "policy")
    assert (policy.base is not None) == residual
    assert policy.meta["training"]["env_steps"] == 40  # the cost travels with a shipped copy
    assert policy.meta["training"]["wall_time_s"] > 0
    assert policy.object_features == "grasp_frame"
    assert "object_class" not in policy.meta["observation_shapes"]
    assert policy.env_kwargs()["classes"] is None
    env = make_env(policy.env_kwargs()["env_id"], pose="oracle", objects=["banana"])
    try:
        policy.bind(env)
        obs, info = env.reset(seed=3)
        policy.reset(obs, info)
        action = policy.act(obs)
        assert action.shape == (6,) and np.all(np.abs(action) <= 1.0)
    finally:
        env.close()
    with pytest.raises(ValueError, match="does not apply to --init-policy"):
        TrainConfig(
            init_policy="learned", normalize=False, hyperparams={"object_features": "grasp_frame"}
        ).validate()
    with pytest.raises(ValueError, match="object_features must be one of class, grasp_frame"):
        TrainConfig(hyperparams={"object_features": "shape"}).validate()
    # a run from before the key read the class one-hot
    old = TrainConfig(hyperparams_entry="scratch").resolved().to_json()
    del old["hyperparams"]["object_features"]
    assert TrainConfig.from_json(old).resolved_hyperparams()["object_features"] == "class"


def test_a_run_from_before_reward_gamma_keeps_the_reward_it_trained_on():
    """A scratch run resolved before reward_gamma existed trained on the normalised reward
    built for 0.99; resuming it under today's scratch entry (built for 0.8) keeps 0.99."""
    old = TrainConfig(hyperparams_entry="scratch").resolved().to_json()
    del old["hyperparams"]["reward_gamma"]
    config = TrainConfig.from_json(old)
    assert config.resolved_hyperparams()["reward_gamma"] == 0.99
    assert TrainConfig(hyperparams_entry="scratch").resolved_hyperparams()["reward_gamma"] == 0.8


def test_init_weights_starts_from_the_policys_networks_and_statistics(tmp_path, capsys):
    """``--init-weights rl_scratch``: the new run's actor, critics and observation statistics
    are the shipped policy's before any update, its policy.json names where it started, a
    resume continues from its own checkpoint (not the initial policy again), and a policy
    that cannot fit (other action type, a residual run) is a one-line error before any work."""
    from safetensors.numpy import load_file

    from scorbot_gym.policies.loading import SHIPPED

    shipped = SHIPPED["rl_scratch"]
    config = TrainConfig(hyperparams_entry="scratch", init_weights="rl_scratch").validate()
    venv = make_vec_env(config)
    model = build_model(config, venv, None)
    weights = load_file(str(shipped / "model.safetensors"))
    for key, value in model.policy.state_dict().items():
        np.testing.assert_array_equal(value.cpu().numpy(), weights[f"policy/{key}"])
    with np.load(shipped / "normalize.npz") as stats:
        np.testing.assert_array_equal(venv.obs_rms["ee_pos"].mean, stats["mean/ee_pos"])
    meta = json.loads((shipped / "policy.json").read_text())
    assert venv.obs_rms["ee_pos"].count == meta["trained_timesteps"]
    venv.close()

    out = tmp_path / "warm"
    argv = [
        "train", "--hyperparams-entry", "scratch", "--init-weights", "rl_scratch", "--pose",
        "occluded", "--objects", "box", "--timesteps", "30", "--learning-starts", "10",
        "--eval-every", "30", "--eval-episodes", "1", "--checkpoint-every", "30",
        "--no-progress", "--no-tensorboard", "--device", "cpu", "--out", str(out),
    ]  # fmt: skip
    assert main(argv) == 0
    policy = json.loads((out / "policy" / "policy.json").read_text())
    assert policy["provenance"]["data"]["init_weights"]["name"] == "rl_scratch"
    assert policy["config"]["pose"] == "occluded" and policy["trained_by"] == "rl_from_scratch"
    trained = load_file(str(out / "policy" / "model.safetensors"))
    assert not np.array_equal(trained["policy/actor.mu.weight"], weights["policy/actor.mu.weight"])
    from scorbot_gym.rl.training import _load_checkpoint

    run_config = TrainConfig.from_json(json.loads((out / "config.json").read_text()))
    venv = make_vec_env(run_config)
    _load_checkpoint(run_config, out, venv)  # as --resume does: its own statistics stay
    assert venv.obs_rms["ee_pos"].count > meta["trained_timesteps"]
    venv.close()
    assert main(["train", "--resume", str(out), "--timesteps", "40", "--no-progress"]) == 0
    capsys.readouterr()
    for bad, why in (
        (["--action-type", "joint"], "its action_type is 'cartesian'"),
        (["--residual"], "excludes residual"),
        (["--init-weights", str(tmp_path / "nothing")], "nothing"),
    ):
        args = ["train", "--hyperparams-entry", "scratch", "--init-weights", "rl_scratch", *bad]
        assert main([*args, "--show-hyperparams"]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and why in err, err
