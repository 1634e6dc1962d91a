"""Learned policies: training, resuming, the shipped policy, the comparison (issue #9)."""

import json
import shutil

import numpy as np
import pytest
from safetensors.torch import save_file

from scorbot_gym.cli import main
from scorbot_gym.envs.factory import make_env
from scorbot_gym.evaluation import run_episode
from scorbot_gym.evaluation.compare import newcombe_paired_diff
from scorbot_gym.policies import ScriptedGraspPolicy
from scorbot_gym.policies.sb3 import SHIPPED_POLICY, ObservationNormalizer, SB3Policy
from scorbot_gym.policies.sb3_files import read_model_file
from scorbot_gym.rl import ResidualActionWrapper, TrainConfig, resume, train
from scorbot_gym.rl.training import build_model, make_vec_env
from scorbot_gym.tasks import FAILURE_CAUSES

pytestmark = pytest.mark.rl


def tiny_config(**kw) -> TrainConfig:
    base = dict(
        algo="sac",
        objects=["box"],
        residual=True,
        timesteps=300,
        hyperparams={
            "learning_starts": 100,
            "batch_size": 64,
            "buffer_size": 2000,
            "net_arch": [32, 32],
        },
        eval_every=150,
        eval_episodes=2,
        checkpoint_every=150,
        bc_demos=1,
        bc_steps=20,
        progress_bar=False,
    )
    return TrainConfig(**{**base, **kw})


@pytest.fixture(scope="session")
def trained_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("rl") / "run"
    state = train(tiny_config(), out)
    return out, state


def test_training_writes_a_loadable_model_checkpoints_and_curve(trained_run):
    out, state = trained_run
    assert state["timesteps"] == 300
    assert [e["timesteps"] for e in state["eval"]] == [0, 150, 300]
    assert all(0.0 <= e["success_rate"] <= 1.0 and e["episodes"] == 2 for e in state["eval"])
    assert state["demos"]["transitions"] > 0
    for name in ("model.safetensors", "replay_buffer.npz", "vecnormalize.json", "state.json"):
        assert (out / "checkpoint" / name).is_file(), name
    assert list((out / "tb").rglob("events.out.tfevents.*"))
    policy = SB3Policy.load(out / "policy")
    assert policy.meta["trained_timesteps"] == 300
    assert policy.meta["saw_scripted_controller"] == {"residual_base": True, "bc_demo_episodes": 1}
    assert not list(out.rglob(".*tmp*")), "temporary files left behind"


@pytest.mark.slow
def test_resume_continues_from_the_checkpoint(trained_run, tmp_path):
    out, state = trained_run
    copy = tmp_path / "run"
    shutil.copytree(out, copy)
    resumed = resume(copy, timesteps=450)
    assert resumed["timesteps"] == 450
    assert resumed["eval"][:3] == state["eval"], "the learning curve so far is kept"
    assert resumed["eval"][-1]["timesteps"] == 450
    assert resumed["wall_s"] > state["wall_s"]
    assert SB3Policy.load(copy / "policy").meta["trained_timesteps"] == 450
    assert json.loads((copy / "config.json").read_text())["timesteps"] == 450


def test_train_refuses_to_overwrite_a_run(trained_run):
    out, _ = trained_run
    with pytest.raises(ValueError, match="already holds a run"):
        train(tiny_config(), out)


@pytest.mark.parametrize("algo", ["tqc", "ppo"])
@pytest.mark.slow
def test_other_algorithms_train_and_export(algo, tmp_path):
    hp = {"n_steps": 32, "batch_size": 32} if algo == "ppo" else {"learning_starts": 32}
    cfg = tiny_config(algo=algo, timesteps=64, hyperparams={"net_arch": [32, 32], **hp})
    cfg.eval_every = 64
    state = train(cfg, tmp_path / algo)
    assert state["timesteps"] >= 64
    policy = SB3Policy.load(tmp_path / algo / "policy")
    assert policy.meta["algo"] == algo
    env = make_env(policy.env_kwargs()["env_id"], objects=["box"])
    obs, info = env.reset(seed=1)
    policy.bind(env).reset(obs, info)
    assert env.action_space.contains(policy.act(obs))


@pytest.mark.slow
def test_same_seed_same_first_updates():
    def params(seed):
        hp = {"learning_starts": 50, "batch_size": 64, "buffer_size": 2000, "net_arch": [32, 32]}
        cfg = tiny_config(residual=False, hyperparams=hp, normalize=False, seed=seed)
        venv = make_vec_env(cfg)
        model = build_model(cfg, venv, None)
        model.learn(120)
        venv.close()
        return np.concatenate([p.detach().numpy().ravel() for p in model.actor.parameters()])

    a, b, c = params(3), params(3), params(4)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_residual_actor_waits_for_a_trained_critic():
    """The residual entry's burn-in: for critic_warmup updates only the critic learns, so the
    correction stays zero (the scripted controller); then the actor moves."""
    from scorbot_gym.rl.finetune import RLPDSAC

    hp = {"learning_starts": 32, "batch_size": 32, "buffer_size": 2000, "net_arch": [32, 32]}
    cfg = tiny_config(hyperparams={**hp, "critic_warmup": 40}, normalize=False)
    venv = make_vec_env(cfg)
    model = build_model(cfg, venv, None)
    assert isinstance(model, RLPDSAC) and model.critic_warmup == 40
    assert model.actor_learning_rate == 3e-6  # the shipped residual entry's

    def flat(module):
        return np.concatenate([p.detach().numpy().ravel() for p in module.parameters()])

    actor0, critic0 = flat(model.actor), flat(model.critic)
    model.learn(32 + 40)  # 40 updates, all in the warm-up
    np.testing.assert_array_equal(flat(model.actor), actor0)
    assert not np.array_equal(flat(model.critic), critic0)
    model.learn(10, reset_num_timesteps=False)
    assert not np.array_equal(flat(model.actor), actor0)
    venv.close()


def test_zero_residual_reproduces_the_scripted_controller():
    plain = make_env("ScorbotGraspCartesian-v0", objects=["box"])
    wrapped = ResidualActionWrapper(make_env("ScorbotGraspCartesian-v0", objects=["box"]))
    scripted = ScriptedGraspPolicy.for_env(plain)
    obs, info = plain.reset(seed=7)
    scripted.reset(obs, info)
    wobs, _ = wrapped.reset(seed=7)
    for _ in range(40):
        action = scripted.act(obs)
        np.testing.assert_allclose(wobs["base_action"], action, atol=1e-6)
        obs, *_ = plain.step(action)
        wobs, _, _, _, winfo = wrapped.step(np.zeros(6, np.float32))
        np.testing.assert_allclose(winfo["applied_action"], action, atol=1e-6)
    np.testing.assert_allclose(wobs["ee_pos"], obs["ee_pos"], atol=1e-9)
    with pytest.raises(ValueError, match="scale"):
        ResidualActionWrapper(plain, scale=0.0)


def test_the_residual_corrects_the_arm_and_leaves_the_gripper_to_the_controller():
    """By default the residual's action has the arm's 5 components; the gripper command is the
    base's whatever the residual does. ``gripper=True`` (and a config from before the setting,
    which corrected it) gives the 6-component residual."""
    from scorbot_gym.rl.training import TrainConfig

    env = make_env("ScorbotGraspCartesian-v0", objects=["box"])
    wrapped = ResidualActionWrapper(env)
    assert wrapped.action_space.shape == (5,)
    wobs, _ = wrapped.reset(seed=7)
    base = wobs["base_action"]
    _, _, _, _, info = wrapped.step(np.ones(5, np.float32))
    applied = info["applied_action"]
    np.testing.assert_allclose(applied[:5], np.clip(base[:5] + 0.3, -1, 1), atol=1e-6)
    assert applied[5] == base[5]
    assert ResidualActionWrapper(env, gripper=True).action_space.shape == (6,)
    old = tiny_config().to_json()
    del old["residual_gripper"]
    assert TrainConfig.from_json(old).residual_gripper is True
    with pytest.raises(ValueError, match="residual_gripper applies only"):
        tiny_config(residual=False, residual_gripper=True).validate()


def test_an_arm_only_residual_policy_keeps_the_base_gripper(trained_run):
    """The exported policy of an arm-only residual run pads its 5 outputs with the base's
    gripper command (the run fixture trains with the default)."""
    out, _ = trained_run
    policy = SB3Policy.load(out / "policy")
    assert policy.meta["residual"]["gripper"] is False
    env = make_env("ScorbotGraspCartesian-v0", objects=["box"])
    policy.bind(env)
    obs, info = env.reset(seed=2)
    policy.reset(obs, info)
    base = ScriptedGraspPolicy(**policy.meta["residual"]["base"])
    base.reset(obs, info)
    for _ in range(30):
        action = policy.act(obs)
        assert action.shape == (6,) and action[5] == base.act(obs)[5]
        obs, *_ = env.step(action)


def test_shipped_policy_loads_and_acts_inside_the_action_space():
    policy = SB3Policy.load(SHIPPED_POLICY)
    kw = policy.env_kwargs()
    env = make_env(kw.pop("env_id"), objects=["banana"])  # one-class one-hot, re-ordered by bind
    policy.bind(env)
    obs, info = env.reset(seed=0)
    policy.reset(obs, info)
    for _ in range(10):
        action = policy.act(obs)
        assert action.shape == env.action_space.shape
        assert env.action_space.contains(action)
        obs, *_ = env.step(action)
    joint = make_env("ScorbotGrasp-v0", objects=["banana"])
    with pytest.raises(ValueError, match="cartesian actions"):
        policy.bind(joint)


def test_components_constant_in_training_are_pinned_at_inference():
    """pose_valid was always 1 under the oracle: an estimator's 0 must not reach the network as
    the clip value (VecNormalize's (0 - 1) / sqrt(1e-8)), but as the training value."""
    norm = ObservationNormalizer(
        {"pose_valid": np.array([1.0]), "object_pos": np.array([0.3, 0.0, 0.8])},
        {"pose_valid": np.array([1e-8]), "object_pos": np.array([1e-3, 4e-3, 1e-3])},
        clip=10.0,
        eps=1e-8,
    )
    out = norm({"pose_valid": np.array([0.0]), "object_pos": np.array([0.3, 0.0, 0.85])})
    assert out["pose_valid"].tolist() == [0.0]
    assert out["object_pos"][2] == pytest.approx(0.05 / np.sqrt(1e-3 + 1e-8), rel=1e-5)
    assert norm.constant["pose_valid"].all() and not norm.constant["object_pos"].any()
    shipped = ObservationNormalizer.load(SHIPPED_POLICY / "normalize.npz").constant
    assert {k for k, c in shipped.items() if c.any()} == {
        "pose_valid",
        "pose_age",
        "pose_confidence",
    }


def test_shipped_policy_on_a_user_added_object(user_object):
    """An object registered by the user is a class the policy never saw (no one-hot slot)."""
    policy = SB3Policy.load(SHIPPED_POLICY)
    kw = policy.env_kwargs()
    env = make_env(kw.pop("env_id"), objects=[user_object.name])
    result = run_episode(env, policy.bind(env), seed=0)
    assert result.object_name == user_object.name
    assert result.steps > 0 and result.failure_cause in (None, *FAILURE_CAUSES)


def test_corrupt_or_incomplete_policy_files_give_clear_errors(tmp_path):
    bad = tmp_path / "bad"
    shutil.copytree(SHIPPED_POLICY, bad)
    (bad / "model.safetensors").write_bytes(b"not a safetensors file at all")
    with pytest.raises(ValueError, match="not a safetensors model file"):
        SB3Policy.load(bad)
    description, tensors = read_model_file(SHIPPED_POLICY / "model.safetensors")
    save_file(tensors, str(bad / "model.safetensors"), metadata={"scorbot_gym": "{broken"})
    with pytest.raises(ValueError, match="no scorbot-gym model description"):
        SB3Policy.load(bad)
    wrong = {**description, "policy_kwargs": {**description["policy_kwargs"], "net_arch": [8]}}
    save_file(tensors, str(bad / "model.safetensors"), metadata={"scorbot_gym": json.dumps(wrong)})
    with pytest.raises(ValueError, match="could not be loaded as a SAC model"):
        SB3Policy.load(bad)
    shutil.copy(SHIPPED_POLICY / "model.safetensors", bad / "model.safetensors")
    meta = json.loads((bad / "policy.json").read_text())
    meta["observation_shapes"]["joint_pos"] = [7]
    (bad / "policy.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match="incompatible policy"):
        SB3Policy.load(bad)
    (bad / "policy.json").write_text("{")
    with pytest.raises(ValueError, match="not valid JSON"):
        SB3Policy.load(bad)
    (bad / "policy.json").unlink()
    with pytest.raises(FileNotFoundError, match="missing policy.json"):
        SB3Policy.load(bad)
    with pytest.raises(SystemExit) as exc:  # checked while parsing
        main(["rollout", "--policy", "rl", "--episodes", "0"])
    assert exc.value.code == 2
    assert main(["train"]) == 2  # neither --out nor --resume
    with pytest.raises(SystemExit) as exc:  # no run folder: checked while parsing
        main(["train", "--resume", str(tmp_path / "nothing")])
    assert exc.value.code == 2
    (tmp_path / "empty").mkdir()
    assert main(["train", "--resume", str(tmp_path / "empty")]) == 2  # no checkpoint


@pytest.mark.slow
def test_compare_writes_json_and_png_with_the_documented_keys(tmp_path):
    js, png = tmp_path / "cmp.json", tmp_path / "cmp.png"
    argv = ["compare", "--policies", "scripted,rl", "--pose", "oracle", "--noise", "0.02"]
    argv += ["--episodes", "2", "--objects", "box", "--json", str(js), "--png", str(png)]
    assert main([*argv, "--no-progress"]) == 0
    report = json.loads(js.read_text())
    assert len(report["results"]) == 4  # 2 policies x (oracle, noisy@0.02)
    for rec in report["results"]:
        for key in ("policy", "pose", "episodes", "success_rate", "ci95", "failure_causes"):
            assert key in rec, key
        assert rec["episodes"] == 2 and len(rec["ci95"]) == 2
        assert set(rec["per_object"]) == {"box"}
    assert [(d["a"], d["b"]) for d in report["differences"]] == [("rl", "scripted")] * 2
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_newcombe_paired_difference():
    same = newcombe_paired_diff([True] * 30, [True] * 30)
    assert same["diff"] == 0 and same["ci95"][0] < 0 < same["ci95"][1]
    assert same["mcnemar_p"] == 1.0
    better = newcombe_paired_diff([True] * 30, [False] * 30)
    assert better["diff"] == 1.0 and better["ci95"][0] > 0.7 and better["mcnemar_p"] < 1e-6
    rng = np.random.default_rng(0)
    a, b = rng.random(200) < 0.8, rng.random(200) < 0.6
    d = newcombe_paired_diff(list(a), list(b))
    assert d["ci95"][0] < d["diff"] < d["ci95"][1]
