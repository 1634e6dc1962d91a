"""Every tensor of an SAC / TQC run on the model's device, after building, saving, restoring and
updating: a checkpoint's tensors are read onto the CPU, and anything of it left there would mix
devices with a CUDA model's batches at the first update ("Expected all tensors to be on the same
device"). This machine has no GPU, so the checks that need a second device use torch's ``meta``
device, on which a model is built and restored without computing anything: a tensor left on the
CPU shows there as it would on CUDA."""

from __future__ import annotations

import dataclasses
import warnings
from types import SimpleNamespace

import gymnasium as gym
import numpy as np
import pytest
import torch as th

from scorbot_gym.policies.sb3_files import read_model_file, restore_training_state, save_model
from scorbot_gym.rl import checkpoint
from scorbot_gym.rl.finetune import DemoMixReplayBuffer, demo_buffer
from scorbot_gym.rl.training import TrainConfig, _load_checkpoint, build_model, make_vec_env, train

pytestmark = pytest.mark.rl

TINY_HP = {"learning_starts": 20, "batch_size": 16, "buffer_size": 500, "net_arch": [16, 16]}


def tiny(algo: str = "sac", **kw) -> TrainConfig:
    """The scratch entry (SAC / TQC with an automatic entropy coefficient), tiny sizes."""
    base = dict(
        algo=algo,
        objects=["box"],
        hyperparams_entry="scratch",
        hyperparams=TINY_HP,
        timesteps=40,
        eval_every=40,
        eval_episodes=1,
        checkpoint_every=40,
        progress_bar=False,
        tensorboard=False,
    )
    return TrainConfig(**{**base, **kw}).validate().resolved()


def on_device(config: TrainConfig, device: str) -> TrainConfig:
    """``config`` on a device validation does not offer (``meta``: a second device here)."""
    return dataclasses.replace(config, device=device)


def misplaced(model, optimizers: list[str] | None = None) -> list[str]:
    """The tensors of ``model`` (weights, the ``optimizers``' parameters and states, default
    all, entropy coefficient, replay buffer) that are not on ``model.device``. Adam's ``step``
    counts are left out: torch keeps them on the CPU unless the optimiser is capturable or
    fused, for a fresh CUDA optimiser too."""
    device = th.device(model.device)
    wrong = [f"policy.{n}" for n, t in model.policy.state_dict().items() if t.device != device]
    if optimizers is None:
        optimizers = [n for n in model._get_torch_save_params()[0] if n != "policy"]
    for name in optimizers:
        optimizer = model
        for part in name.split("."):
            optimizer = getattr(optimizer, part)
        for i, state in optimizer.state.items():
            wrong += [
                f"{name}.state[{i}].{k}"
                for k, v in state.items()
                if k != "step" and isinstance(v, th.Tensor) and v.device != device
            ]
        for group in optimizer.param_groups:
            wrong += [f"{name} parameter" for p in group["params"] if p.device != device]
    for name in ("log_ent_coef", "ent_coef_tensor"):
        value = getattr(model, name, None)
        if isinstance(value, th.Tensor) and value.device != device:
            wrong.append(f"{name} on {value.device}")
    buffer = getattr(model, "replay_buffer", None)
    if buffer is not None and th.device(buffer.device) != device:
        wrong.append(f"replay_buffer on {buffer.device}")
    return wrong


def entropy_optimiser_holds_log_ent_coef(model) -> bool:
    """The entropy optimiser steps the model's own ``log_ent_coef``, not a stale copy."""
    params = [p for g in model.ent_coef_optimizer.param_groups for p in g["params"]]
    return len(params) == 1 and params[0] is model.log_ent_coef


#: the optimisers checked on ``meta``: SB3 builds the actor's and critics' optimisers before it
#: moves the policy to its device; ``Module.to`` keeps the ``Parameter`` objects when it moves
#: them to CUDA (``set_data``) but makes new ones on ``meta``, whose optimisers then still hold
#: the CPU parameters (and put their restored state there): an artefact of ``meta``, left out.
#: The CPU test checks every optimiser.
META_CHECKED = ["ent_coef_optimizer"]


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A tiny scratch SAC run: its checkpoint holds updated optimisers and entropy coefficient."""
    out = tmp_path_factory.mktemp("device") / "run"
    config = tiny()
    train(config, out)
    return config, out


def test_a_cpu_run_saves_restores_and_updates_with_everything_on_its_device(trained):
    config, out = trained
    description, tensors = read_model_file(out / "checkpoint" / checkpoint.MODEL)
    assert description["progress"]["n_updates"] > 0, "the checkpoint has updated optimisers"
    saved = tensors["variables/log_ent_coef"].clone()
    venv = make_vec_env(config)
    try:
        model = _load_checkpoint(config, out, venv)
        assert misplaced(model) == []
        assert entropy_optimiser_holds_log_ent_coef(model)
        assert th.equal(model.log_ent_coef.detach(), saved), "log_ent_coef restored"
        assert model.actor.optimizer.state, "the optimiser state was restored"
        model._last_obs = None
        model.learn(10, reset_num_timesteps=False)
        assert misplaced(model) == []
        assert entropy_optimiser_holds_log_ent_coef(model)
        assert not th.equal(model.log_ent_coef.detach(), saved), "the updates moved it"
    finally:
        venv.close()


@pytest.mark.parametrize("algo", ["sac", "tqc"])
def test_a_checkpoint_written_on_the_cpu_restores_onto_another_device(algo, tmp_path, monkeypatch):
    """A run trained on the CPU and resumed with ``--device cuda`` (or any checkpoint, whose
    tensors are always read onto the CPU): nothing of the file stays on the CPU."""
    config = tiny(algo)
    venv = make_vec_env(config)
    try:
        save_model(build_model(config, venv, None), tmp_path / "model.safetensors", training=True)
        model = build_model(on_device(config, "meta"), venv, None)
        assert misplaced(model, META_CHECKED) == [], "a freshly built model is on its device"
        asked = []
        set_parameters = type(model).set_parameters

        def recording(self, params, exact_match=True, device="auto"):
            asked.append(device)
            return set_parameters(self, params, exact_match, device)

        monkeypatch.setattr(type(model), "set_parameters", recording)
        with warnings.catch_warnings():  # loading into meta tensors computes nothing (a no-op)
            warnings.filterwarnings("ignore", message=".*meta parameter.*")
            restore_training_state(model, tmp_path / "model.safetensors")
    finally:
        venv.close()
    assert [str(d) for d in asked] == ["meta"], "the restore names the model's device"
    assert misplaced(model, META_CHECKED) == []
    assert entropy_optimiser_holds_log_ent_coef(model)


def test_fine_tune_demonstrations_sample_on_the_models_device(tmp_path):
    """The fine-tune's demonstration buffer, built (demo_buffer) or read back from a
    checkpoint, gives batches on the online buffer's device: its rows join them (th.cat)."""
    obs_space = gym.spaces.Box(-10, 10, (3,), np.float32)
    act_space = gym.spaces.Box(-1, 1, (2,), np.float32)
    model = SimpleNamespace(
        observation_space=obs_space, action_space=act_space, device=th.device("meta")
    )
    n = 6
    transitions = {
        "observations": np.ones((n, 3), np.float32),
        "next_observations": np.ones((n, 3), np.float32),
        "actions": np.zeros((n, 2), np.float32),
        "rewards": np.zeros(n, np.float32),
        "dones": np.zeros(n, np.float32),
    }
    online = DemoMixReplayBuffer(50, obs_space, act_space, device="meta", demo_ratio=0.5)
    for _ in range(10):
        o = np.ones((1, 3), np.float32)
        online.add(o, o, np.zeros((1, 2)), np.zeros(1), np.zeros(1), [{}])
    online.demos = demo_buffer(transitions, model)
    assert online.sample(8).observations.device == th.device("meta")

    checkpoint.save_replay_buffer(online, tmp_path / "buffer.npz")
    resumed = DemoMixReplayBuffer(50, obs_space, act_space, device="meta", demo_ratio=0.5)
    checkpoint.load_replay_buffer(resumed, tmp_path / "buffer.npz")
    assert th.device(resumed.demos.device) == th.device("meta")
    assert resumed.sample(8).observations.device == th.device("meta")
