"""Loading never runs code (#50 deliverable 1): every loader of a policy or a training run is
fed a crafted pickle payload (its ``__reduce__`` creates a marker folder) and must refuse it in
one line without running it; the safe formats round-trip everything a resumed run needs; old
pickle-based folders are converted only with ``--trust-pickle``; the shipped ``rl`` policy acts
as it did before its conversion."""

from __future__ import annotations

import base64
import json
import os
import pickle
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch as th
from safetensors.torch import save_file

from scorbot_gym.cli import main
from scorbot_gym.policies.loading import load_policy
from scorbot_gym.policies.sb3 import SHIPPED_POLICY, SB3Policy
from scorbot_gym.policies.sb3_files import load_model, read_model_file, restore_training_state
from scorbot_gym.policies.sb3_files import save_model as save_safe_model
from scorbot_gym.rl import checkpoint
from scorbot_gym.rl.training import TrainConfig, build_model, make_vec_env, resume, train

pytestmark = pytest.mark.rl

FIXTURE = Path(__file__).parent / "data" / "shipped_rl_actions.npz"


class Payload:
    """What an attacker pickles: unpickling it calls ``os.mkdir(marker)``."""

    def __init__(self, marker: Path) -> None:
        self.marker = str(marker)

    def __reduce__(self):
        return (os.mkdir, (self.marker,))


def payload_bytes(marker: Path) -> bytes:
    return pickle.dumps(Payload(marker))


def crafted_sb3_zip(path: Path, marker: Path) -> None:
    """An SB3 archive whose ``data`` has a ``":serialized:"`` entry holding the payload (what
    SB3's ``.load`` unpickles with cloudpickle)."""
    entry = {":type:": "<class 'type'>", ":serialized:": base64.b64encode(payload_bytes(marker))}
    data = {"policy_class": {k: v if isinstance(v, str) else v.decode() for k, v in entry.items()}}
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("data", json.dumps(data))
        z.writestr("policy.pth", payload_bytes(marker))


def npz_with_object_array(path: Path, marker: Path) -> None:
    """An ``.npz`` whose array is an object array, i.e. a pickle of the payload."""
    np.savez(path, clip=np.array([Payload(marker)], dtype=object))


def one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    return err


def test_the_payloads_are_live(tmp_path):
    """The crafted files do run code when read the old way (so the tests below can fail)."""
    from stable_baselines3.common.save_util import json_to_data

    marker = tmp_path / "ran"
    crafted_sb3_zip(tmp_path / "model.zip", marker)
    with zipfile.ZipFile(tmp_path / "model.zip") as z:
        json_to_data(z.read("data").decode())
    assert marker.is_dir()
    os.rmdir(marker)
    npz_with_object_array(tmp_path / "n.npz", marker)
    with np.load(tmp_path / "n.npz", allow_pickle=True) as z:
        z["clip"]
    assert marker.is_dir()


# --- policy folders (rollout --policy DIR, compare --policies scripted,DIR) --------------------
@pytest.fixture
def policy_copy(tmp_path) -> Path:
    folder = tmp_path / "policy"
    shutil.copytree(SHIPPED_POLICY, folder)
    return folder


def test_an_old_format_policy_with_a_payload_is_refused_unread(policy_copy, tmp_path, capsys):
    marker = tmp_path / "ran"
    (policy_copy / "model.safetensors").unlink()
    crafted_sb3_zip(policy_copy / "model.zip", marker)
    argv = ["rollout", "--policy", str(policy_copy), "--episodes", "1", "--objects", "box"]
    assert main(argv) == 2
    err = one_line_error(capsys)
    assert "old pickle-based format" in err and f"scorbot-gym convert {policy_copy}" in err
    argv = ["compare", "--policies", f"scripted,{policy_copy}", "--episodes", "1"]
    assert main([*argv, "--objects", "box"]) == 2
    assert "--trust-pickle" in one_line_error(capsys)
    with pytest.raises(ValueError, match="old pickle-based format"):
        load_policy(policy_copy)
    assert not marker.exists()


@pytest.mark.parametrize("kind", ["pickle", "sb3_zip"])
def test_a_payload_named_model_safetensors_is_refused(policy_copy, tmp_path, kind, capsys):
    marker = tmp_path / "ran"
    target = policy_copy / "model.safetensors"
    if kind == "pickle":
        target.write_bytes(payload_bytes(marker))
    else:
        crafted_sb3_zip(target, marker)
    assert main(["rollout", "--policy", str(policy_copy), "--episodes", "1"]) == 2
    assert "is not a safetensors model file" in one_line_error(capsys)
    assert not marker.exists()


@pytest.mark.parametrize(
    ("where", "key", "value", "message"),
    [
        ("hyperparams", "replay_buffer_class", "os.system", "a file cannot name code"),
        ("policy_kwargs", "activation_fn", "builtins.exec", "a file cannot name code"),
        ("policy_kwargs", "features_extractor_class", "os.mkdir", "a file cannot name code"),
        ("hyperparams", "not_a_setting", 1, "unknown hyperparameters for SAC"),
        (None, "class", "os.system", "class 'os.system' is not one of"),
        (None, "policy", "subprocess.Popen", "policy 'subprocess.Popen' is not one of"),
    ],
)
def test_a_model_description_cannot_name_code(policy_copy, where, key, value, message):
    description, tensors = read_model_file(policy_copy / "model.safetensors")
    (description[where] if where else description)[key] = value
    meta = {"scorbot_gym": json.dumps(description)}
    save_file(tensors, str(policy_copy / "model.safetensors"), metadata=meta)
    with pytest.raises(ValueError, match=message):
        SB3Policy.load(policy_copy)


def test_normalisation_statistics_holding_a_pickle_are_refused(policy_copy, tmp_path, capsys):
    marker = tmp_path / "ran"
    npz_with_object_array(policy_copy / "normalize.npz", marker)
    assert main(["rollout", "--policy", str(policy_copy), "--episodes", "1"]) == 2
    assert "normalize.npz is damaged" in one_line_error(capsys)
    assert not marker.exists()


def test_imitation_weights_holding_a_pickle_are_refused(tmp_path, capsys):
    from scorbot_gym.policies.imitation import SHIPPED_LEARNED_POLICY

    marker, folder = tmp_path / "ran", tmp_path / "learned"
    shutil.copytree(SHIPPED_LEARNED_POLICY, folder)
    np.savez(folder / "weights.npz", w0=np.array([Payload(marker)], dtype=object))
    assert main(["rollout", "--policy", str(folder), "--episodes", "1"]) == 2
    assert "could not be read as policy weights" in one_line_error(capsys)
    assert not marker.exists()


def test_a_pose_model_file_holding_a_pickle_is_refused(tmp_path, capsys):
    marker, model = tmp_path / "ran", tmp_path / "models.npz"
    np.savez(model, __header__=np.array([Payload(marker)], dtype=object))
    argv = ["rollout", "--pose", "manifold", "--pose-model", str(model), "--episodes", "1"]
    assert main(argv) == 2
    assert "corrupt model file" in one_line_error(capsys)
    assert not marker.exists()


def test_the_shipped_rl_policy_acts_as_before_its_conversion():
    """The observations and actions recorded with SB3's own loader on the old ``model.zip``
    (3 episodes, 180 steps); the converted policy gives the same actions, bit for bit."""
    policy = SB3Policy.load(SHIPPED_POLICY)
    assert not (SHIPPED_POLICY / "model.zip").exists(), "the package ships no pickle"
    from scorbot_gym.envs.factory import make_env

    env = make_env(**policy.env_kwargs(), objects=["box"])
    policy.bind(env)
    env.close()
    with np.load(FIXTURE, allow_pickle=False) as z:
        keys = [k[4:] for k in z.files if k.startswith("obs/")]
        episode, actions = z["episode"], z["actions"]
        obs = {k: z[f"obs/{k}"] for k in keys}
    for i in range(len(episode)):
        o = {k: v[i] for k, v in obs.items()}
        if i == 0 or episode[i] != episode[i - 1]:
            policy.reset(o, None)
        np.testing.assert_array_equal(policy.act(o), actions[i])


def test_an_old_policy_folder_converts_with_trust_and_acts_the_same(policy_copy, capsys):
    """A genuine old folder (SB3's ``.save``): refused without --trust-pickle (nothing written),
    converted with it (the old file left in place), then identical to the shipped policy."""
    load_model(SHIPPED_POLICY / "model.safetensors").save(policy_copy / "model.zip")
    (policy_copy / "model.safetensors").unlink()
    assert main(["convert", str(policy_copy)]) == 2
    assert "--trust-pickle" in one_line_error(capsys)
    assert not (policy_copy / "model.safetensors").exists()
    assert main(["convert", str(policy_copy), "--trust-pickle"]) == 0
    assert "wrote" in capsys.readouterr().out
    assert (policy_copy / "model.zip").is_file() and (policy_copy / "model.safetensors").is_file()
    assert main(["convert", str(policy_copy)]) == 0  # nothing left to convert
    assert "nothing to convert" in capsys.readouterr().out
    a, b = SB3Policy.load(policy_copy), SB3Policy.load(SHIPPED_POLICY)
    for k, v in a.model.policy.state_dict().items():
        assert th.equal(v, b.model.policy.state_dict()[k]), k


# --- training runs (train --resume) ------------------------------------------------------------
def tiny(**kw) -> TrainConfig:
    base = dict(
        objects=["box"],
        timesteps=60,
        hyperparams={"learning_starts": 30, "batch_size": 16, "buffer_size": 500},
        eval_every=60,
        eval_episodes=1,
        checkpoint_every=60,
        progress_bar=False,
        tensorboard=False,
    )
    return TrainConfig(**{**base, **kw})


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("safe") / "run"
    train(tiny(), out)
    return out


@pytest.fixture
def run_copy(tiny_run, tmp_path) -> Path:
    run = tmp_path / "run"
    shutil.copytree(tiny_run, run)
    return run


def test_a_checkpoint_round_trips_everything_a_resumed_run_needs(tmp_path):
    """Weights, optimiser states, the entropy coefficient, counters and the replay buffer come
    back exactly into a model built afresh from the configuration."""
    cfg = tiny(normalize=False)
    venv = make_vec_env(cfg)
    try:
        model = build_model(cfg, venv, None)
        model.learn(50)
        save_safe_model(model, tmp_path / "m.safetensors", training=True)
        checkpoint.save_replay_buffer(model.replay_buffer, tmp_path / "b.npz")
        fresh = build_model(cfg, venv, None)
        restore_training_state(fresh, tmp_path / "m.safetensors")
        checkpoint.load_replay_buffer(fresh.replay_buffer, tmp_path / "b.npz")
    finally:
        venv.close()
    for name in ("policy", "actor.optimizer", "critic.optimizer", "ent_coef_optimizer"):
        a, b = (m.policy if name == "policy" else _attr(m, name) for m in (model, fresh))
        assert _flat(a.state_dict()) == _flat(b.state_dict()), name
    assert th.equal(model.log_ent_coef, fresh.log_ent_coef)
    assert (fresh.num_timesteps, fresh._n_updates) == (50, 50 - 30)
    assert list(fresh.ep_info_buffer) == list(model.ep_info_buffer)
    assert (fresh.replay_buffer.pos, fresh.replay_buffer.full) == (50, False)
    for k, v in model.replay_buffer.observations.items():
        np.testing.assert_array_equal(fresh.replay_buffer.observations[k], v)
    np.testing.assert_array_equal(fresh.replay_buffer.actions, model.replay_buffer.actions)


def _attr(obj, dotted: str):
    for part in dotted.split("."):
        obj = getattr(obj, part)
    return obj


def _flat(state, prefix="") -> dict:
    """A (nested) state dict as comparable plain values."""
    if isinstance(state, th.Tensor):
        return {prefix: state.tolist()}
    if isinstance(state, dict):
        return {k2: v2 for k, v in state.items() for k2, v2 in _flat(v, f"{prefix}/{k}").items()}
    if isinstance(state, (list, tuple)):
        return {k2: v2 for i, v in enumerate(state) for k2, v2 in _flat(v, f"{prefix}/{i}").items()}
    return {prefix: state}


@pytest.mark.parametrize("name", ["model.safetensors", "replay_buffer.npz", "vecnormalize.json"])
def test_a_checkpoint_file_replaced_by_a_payload_is_refused(run_copy, tmp_path, name, capsys):
    marker = tmp_path / "ran"
    path = run_copy / "checkpoint" / name
    if name.endswith(".npz"):
        npz_with_object_array(path, marker)
    else:
        path.write_bytes(payload_bytes(marker))
    assert main(["train", "--resume", str(run_copy), "--timesteps", "90", "--no-progress"]) == 2
    err = one_line_error(capsys)
    assert "cannot resume" in err and name in err
    assert not marker.exists()


def test_an_old_format_run_with_payloads_is_refused_unread(run_copy, tmp_path, capsys):
    marker = tmp_path / "ran"
    ck = run_copy / "checkpoint"
    for new, old in checkpoint.OLD_FILES.items():
        (ck / new).unlink()
        if old.endswith(".zip"):
            crafted_sb3_zip(ck / old, marker)
        else:
            (ck / old).write_bytes(payload_bytes(marker))
    assert main(["train", "--resume", str(run_copy), "--no-progress"]) == 2
    err = one_line_error(capsys)
    assert f"scorbot-gym convert {run_copy} --trust-pickle" in err
    assert main(["convert", str(run_copy)]) == 2
    err = one_line_error(capsys)
    assert "replay_buffer.pkl" in err and "--trust-pickle" in err
    with pytest.raises(ValueError, match="old pickle-based format"):
        resume(run_copy)
    assert not marker.exists()
    assert not any((ck / new).exists() for new in checkpoint.OLD_FILES), "nothing written"


def test_an_old_format_run_converts_with_trust_and_resumes(run_copy, capsys):
    """A genuine old checkpoint (SB3's ``.save``, ``save_replay_buffer``, ``VecNormalize.save``)
    converts in one command and the run continues from it."""
    cfg = TrainConfig.from_json(json.loads((run_copy / "config.json").read_text()))
    ck = run_copy / "checkpoint"
    venv = make_vec_env(cfg)
    try:
        checkpoint.load_vec_normalize(venv, ck / checkpoint.VEC_NORMALIZE)
        model = build_model(cfg, venv, None)
        restore_training_state(model, ck / checkpoint.MODEL)
        checkpoint.load_replay_buffer(model.replay_buffer, ck / checkpoint.REPLAY_BUFFER)
        model.save(ck / "model.zip")
        model.save_replay_buffer(ck / "replay_buffer.pkl")
        venv.save(str(ck / "vecnormalize.pkl"))
    finally:
        venv.close()
    stats = json.loads((ck / checkpoint.VEC_NORMALIZE).read_text())
    for new in checkpoint.OLD_FILES:
        (ck / new).unlink()
    assert main(["convert", str(run_copy), "--trust-pickle"]) == 0
    out = capsys.readouterr().out
    assert all(new in out for new in checkpoint.OLD_FILES), out
    assert json.loads((ck / checkpoint.VEC_NORMALIZE).read_text())["obs_rms"] == stats["obs_rms"]
    with np.load(ck / checkpoint.REPLAY_BUFFER, allow_pickle=False) as z:
        assert json.loads(str(z["layout"]))["rows"] == 60
    state = resume(run_copy, timesteps=90)
    assert state["timesteps"] == 90


def test_a_fine_tunes_demonstration_buffer_round_trips(tmp_path):
    """The fine-tune's buffer keeps its demonstrations in a buffer of its own (``demos``)."""
    from gymnasium import spaces

    from scorbot_gym.rl.finetune import DemoMixReplayBuffer, demo_buffer

    obs_space = spaces.Box(-5.0, 5.0, (7,), np.float32)
    act_space = spaces.Box(-1.0, 1.0, (3,), np.float32)

    def fresh() -> DemoMixReplayBuffer:
        return DemoMixReplayBuffer(40, obs_space, act_space, device="cpu", demo_ratio=0.5)

    class Spaces:  # what demo_buffer reads of a model
        observation_space, action_space, device = obs_space, act_space, "cpu"

    rng = np.random.default_rng(0)
    buffer = fresh()
    for _ in range(45):  # wraps around: all 40 rows, pos 5
        o, a = rng.normal(size=(1, 7)), rng.uniform(-1, 1, (1, 3))
        buffer.add(o, o + 1, a, np.ones(1), np.zeros(1), [{}])
    n = 12
    buffer.demos = demo_buffer(
        {
            "observations": rng.normal(size=(n, 7)),
            "next_observations": rng.normal(size=(n, 7)),
            "actions": rng.uniform(-1, 1, (n, 3)),
            "rewards": rng.normal(size=n),
            "dones": np.zeros(n),
        },
        Spaces,
    )
    buffer.demo_rows_drawn = 17
    checkpoint.save_replay_buffer(buffer, tmp_path / "b.npz")
    loaded = fresh()
    checkpoint.load_replay_buffer(loaded, tmp_path / "b.npz")
    assert (loaded.pos, loaded.full, loaded.demo_rows_drawn) == (5, True, 17)
    for field in ("observations", "next_observations", "actions", "rewards", "dones"):
        np.testing.assert_array_equal(getattr(loaded, field), getattr(buffer, field))
        np.testing.assert_array_equal(getattr(loaded.demos, field), getattr(buffer.demos, field))
    assert loaded.demos.size() == n
    with pytest.raises(ValueError, match="buffer_size 40 differs from the run's 50"):
        checkpoint.load_replay_buffer(
            DemoMixReplayBuffer(50, obs_space, act_space, device="cpu"), tmp_path / "b.npz"
        )


def test_a_damaged_old_file_is_a_one_line_error_even_when_trusted(policy_copy, capsys):
    (policy_copy / "model.safetensors").unlink()
    (policy_copy / "model.zip").write_bytes(b"half a zip")
    assert main(["convert", str(policy_copy), "--trust-pickle"]) == 2
    assert f"cannot convert {policy_copy}" in one_line_error(capsys)
    assert not (policy_copy / "model.safetensors").exists()
    assert main(["convert", str(policy_copy / "nothing")]) == 2
    assert "no policy folder or training run folder" in one_line_error(capsys)
