"""RL fine-tuning of the imitation policy, RLPD-style (#36 item 2): the SAC actor starts as the
imitation policy, demonstrations are in every batch, the critic warms up before the actor
moves, a run writes a stand-alone policy that ``load_policy`` / ``rollout --policy`` load, and
the same seed gives the same first updates. Real SB3 and MuJoCo, tiny sizes."""

from __future__ import annotations

import json

import numpy as np
import pytest
from stable_baselines3.common.buffers import ReplayBuffer

from scorbot_gym.cli import main
from scorbot_gym.policies.imitation import ImitationPolicy
from scorbot_gym.policies.loading import load_policy
from scorbot_gym.rl.finetune import (
    DemoMixReplayBuffer,
    ImitationFeatures,
    demo_buffer,
    demo_transitions,
    executed_action,
    load_init_policy,
)
from scorbot_gym.rl.imitation import collect_episodes
from scorbot_gym.rl.training import (
    TrainConfig,
    build_model,
    make_policy_env,
    make_vec_env,
    train,
)

pytestmark = pytest.mark.rl

TINY_HP = {"batch_size": 16, "critic_warmup": 16, "buffer_size": 1000}


def tiny(**kw) -> TrainConfig:
    base = dict(
        init_policy="learned",
        normalize=False,
        objects=["box"],
        timesteps=48,
        bc_demos=1,
        hyperparams=TINY_HP,
        eval_every=48,
        eval_episodes=1,
        checkpoint_every=48,
        progress_bar=False,
        tensorboard=False,
    )
    return TrainConfig(**{**base, **kw}).validate().resolved()


def _params(module) -> np.ndarray:
    return np.concatenate([p.detach().numpy().ravel() for p in module.parameters()])


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("finetune") / "run"
    state = train(tiny(seed=3), out)
    return out, state


@pytest.mark.slow
def test_actor_initialised_from_the_imitation_policy_acts_like_it():
    """Before any update, SAC's deterministic action (through the fine-tune's features and
    gripper execution) is the imitation policy's, step after step of a seeded episode."""
    config = tiny()
    venv = make_vec_env(config)
    try:
        model = build_model(config, venv, None)
        bc = load_policy("learned")
        raw = make_policy_env(config)
        wrapped = ImitationFeatures(make_policy_env(config), load_init_policy("learned"))
        obs, _ = raw.reset(seed=11)
        feats, _ = wrapped.reset(seed=11)
        bc.reset(obs)
        for _ in range(40):
            want = bc.act(obs)
            got, _ = model.predict(feats, deterministic=True)
            got = executed_action(got)
            np.testing.assert_allclose(got[:-1], want[:-1], atol=1e-5)
            assert got[-1] == want[-1]
            obs, *_ = raw.step(want)
            feats, *_ = wrapped.step(want)
    finally:
        venv.close()


def test_demo_rows_are_in_every_batch():
    """Half of each batch comes from the demonstration buffer, the rest from online data."""
    import gymnasium as gym

    obs_space = gym.spaces.Box(-10, 10, (3,), np.float32)
    act_space = gym.spaces.Box(-1, 1, (2,), np.float32)
    online = DemoMixReplayBuffer(100, obs_space, act_space, device="cpu", demo_ratio=0.5)
    for _ in range(30):
        o = np.ones((1, 3), np.float32)
        online.add(o, o, np.zeros((1, 2)), np.zeros(1), np.zeros(1), [{}])
    demos = ReplayBuffer(20, obs_space, act_space, device="cpu")
    for _ in range(20):
        o = -np.ones((1, 3), np.float32)
        demos.add(o, o, np.zeros((1, 2)), np.zeros(1), np.zeros(1), [{}])
    online.demos = demos
    batch = online.sample(16)
    first = batch.observations[:, 0].numpy()
    np.testing.assert_array_equal(first[:8], -1.0)  # demonstrations first (for the BC term)
    np.testing.assert_array_equal(first[8:], 1.0)
    assert online.last_demo_rows == 8 and online.demo_rows_drawn == 8


@pytest.mark.slow
def test_tiny_fine_tune_writes_a_loadable_stand_alone_policy(tiny_run, tmp_path, capsys):
    out, state = tiny_run
    policy = load_policy(out, checkpoint="last")
    assert isinstance(policy, ImitationPolicy) and policy.uses_scripted_controller is False
    meta = json.loads((out / "policy" / "policy.json").read_text())
    assert meta["uses_scripted_controller"] is False
    record = meta["training"]
    assert record["rl_finetune"]["env_steps"] == 48
    assert record["rl_finetune"]["demonstration_episodes"] == 1
    assert record["demonstration_episodes"] == record["imitation"]["demonstration_episodes"] + 1
    assert record["env_steps"] == record["imitation"]["env_steps"] + 48
    assert record["wall_time_s"] > record["imitation"]["wall_time_s"]
    # compare's training column: both stages, although the run's own state counts RL steps only
    from scorbot_gym.evaluation.compare import training_record

    row = training_record(out / "policy", meta)
    assert row["trained_from"] == "demonstrations" and row["env_steps"] == record["env_steps"]
    # the demonstrations were drawn in the batches: 48 updates, 8 demo rows each
    assert state["demos"]["transitions"] > 0
    env = make_policy_env(tiny())
    obs, _ = env.reset(seed=0)
    policy.bind(env).reset(obs)
    for _ in range(5):
        action = policy.act(obs)
        assert env.action_space.contains(action)
        obs, *_ = env.step(action)
    assert (out / "checkpoint" / "model.safetensors").is_file()
    assert main(["rollout", "--policy", str(out), "--episodes", "1", "--objects", "box"]) == 0
    assert "success" in capsys.readouterr().out.lower()


@pytest.mark.slow
def test_same_seed_same_first_updates_and_the_actor_waits_for_the_critic():
    """Two fine-tunes with one seed make identical updates; another seed differs. During the
    critic warm-up only the critic moves."""

    def after_updates(seed: int):
        config = tiny(seed=seed)
        venv = make_vec_env(config)
        try:
            model = build_model(config, venv, None)
            env = make_policy_env(config)
            episodes = collect_episodes(env, [seed], dart_sigma=0.2)
            model.replay_buffer.demos = demo_buffer(
                demo_transitions(episodes, load_init_policy("learned")), model
            )
            actor0, critic0 = _params(model.actor), _params(model.critic)
            model.learn(16)  # 16 updates = critic_warmup: the actor is frozen
            np.testing.assert_array_equal(actor0, _params(model.actor))
            assert not np.array_equal(critic0, _params(model.critic))
            model.learn(8, reset_num_timesteps=False)
            assert not np.array_equal(actor0, _params(model.actor)), "then the actor moves"
            assert model.replay_buffer.demo_rows_drawn == 8 * model._n_updates == 8 * 24
            return _params(model.actor), _params(model.critic)
        finally:
            venv.close()

    a1, c1 = after_updates(5)
    a2, c2 = after_updates(5)
    np.testing.assert_array_equal(a1, a2)
    np.testing.assert_array_equal(c1, c2)
    _, c3 = after_updates(6)
    assert not np.array_equal(c1, c3)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--init-policy", "rl"], "is not an imitation policy"),
        (["--init-policy", "learned", "--algo", "tqc"], "fine-tunes with algo 'sac'"),
        (["--init-policy", "learned", "--net-arch", "64", "64"], "net_arch must be"),
        (["--hyperparams", "bc_coef=0.1"], "bc_coef applies only to fine-tuning"),
    ],
)
def test_bad_fine_tune_options_are_one_line_errors(argv, message, tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["train", "--out", str(out), *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err, err
    assert not out.exists()


@pytest.mark.slow
def test_the_benchmark_refuses_bad_settings_before_training(tmp_path):
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    proc = subprocess.run(
        [sys.executable, "benchmarks/finetune.py", "--hyperparams", "bc_coef=-1"],
        cwd=root,
        env={**os.environ, "PYTHONPATH": str(root), "MUJOCO_GL": "egl"},
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    assert "bc_coef must be a number in [0.0, inf)" in proc.stderr.strip().splitlines()[-1]


def test_the_packaged_fine_tuned_policy_loads_stand_alone_and_records_both_stages():
    from pathlib import Path

    import scorbot_gym

    folder = Path(scorbot_gym.__file__).parent / "policies" / "data" / "imitation_rlpd_oracle"
    size = sum(f.stat().st_size for f in folder.iterdir())
    assert size < 2 * 2**20
    policy = load_policy(folder)
    assert isinstance(policy, ImitationPolicy) and policy.uses_scripted_controller is False
    record = policy.meta["training"]
    assert record["rl_finetune"]["env_steps"] > 0 and record["imitation"]["dagger_episodes"] > 0
