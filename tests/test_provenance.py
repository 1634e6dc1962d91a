"""Provenance that rebuilds (#49 item 6): every ``policy.json`` says how it was trained, with
the command, code commit, data and pose-model identity; Minari datasets record their env
(``recover_environment()`` works) and action type, and the imitation trainer refuses a dataset
of another action type and records the dataset's settings; benchmark scripts write to a fresh
run folder and never over an existing file unless told.
"""

from __future__ import annotations

import hashlib
import json
import runpy
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from scorbot_gym import make_env, seeds
from scorbot_gym.experiments.outputs import Outputs, companion
from scorbot_gym.rl import provenance
from scorbot_gym.rl.imitation import ImitationConfig, train_imitation

pytestmark = pytest.mark.rl

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = sorted((ROOT / "scorbot_gym" / "policies" / "data").glob("*/policy.json"))
TINY = ImitationConfig(demos=2, dagger_rounds=1, dagger_episodes=1, fit_steps=5, hidden=(8,))


def _git_head() -> str | None:
    done = subprocess.run(
        ["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True, text=True, check=False
    )
    return done.stdout.strip() if done.returncode == 0 else None


@pytest.fixture(scope="module")
def box_env():
    env = make_env("ScorbotGraspCartesian-v0", pose="oracle", objects=["box"])
    yield env
    env.close()


@pytest.fixture(scope="module")
def tiny_policy(box_env):
    policy, _ = train_imitation(box_env, TINY)
    return policy


# --- what a new policy records ----------------------------------------------------------------


def test_an_imitation_policy_records_command_code_data_and_no_pose_models(tiny_policy, tmp_path):
    tiny_policy.save(tmp_path / "p")
    meta = json.loads((tmp_path / "p" / "policy.json").read_text())
    assert meta["trained_by"] == "imitation"
    prov = meta["provenance"]
    assert prov["command"] == sys.argv
    head = _git_head()
    if head is not None:  # a checkout: the commit; a wheel: unknown, honestly
        assert prov["code"]["commit"] == head
        assert isinstance(prov["code"]["uncommitted_changes"], bool)
    assert prov["code"]["version"] == "0.1.0"
    assert prov["pose_models"] is None, "the oracle pose has no models"
    demos, dagger = prov["data"]["demonstrations"], prov["data"]["dagger"]
    assert demos["kind"] == "collected" and demos["episodes"] == 2 and demos["dart_sigma"] == 0.2
    assert demos["seeds"] == {
        "first": seeds.DEMONSTRATIONS.start,
        "last": seeds.DEMONSTRATIONS.start + 1,
        "count": 2,
        "range": "demonstrations",
    }
    assert dagger["range"] == "dagger" and dagger["first"] == seeds.DAGGER.start
    assert {"torch", "numpy", "mujoco"} <= set(prov["libraries"])


def test_the_episodes_a_trainer_collects_are_on_training_seeds(box_env):
    """Demonstrations and DAgger take their seeds from their blocks, none an evaluation seed
    (DAgger used to start at 1,000,000: the seeds of every training run's evaluations)."""
    from scorbot_gym.rl import imitation

    played: list[int] = []
    real = imitation.collect_episodes

    def spy(env, seed_list, **kwargs):
        played.extend(int(s) for s in seed_list)
        return real(env, seed_list, **kwargs)

    imitation.collect_episodes = spy
    try:
        train_imitation(box_env, ImitationConfig(**{**TINY.__dict__, "seed": 2}))
    finally:
        imitation.collect_episodes = real
    assert played[:2] == list(seeds.DEMONSTRATIONS.block(2, 2))
    assert played[2:] == list(seeds.DAGGER.block(2, 1))
    for s in played:
        assert seeds.range_of(s).purpose == "training", s


def test_pose_model_identity_hashes_the_file_or_the_models(tmp_path):
    from pose.model_set import PoseModelSet

    assert provenance.pose_model_identity(None) is None
    f = tmp_path / "m.npz"
    f.write_bytes(b"not really a model")
    ident = provenance.pose_model_identity(f)
    assert ident == {"file": str(f), "sha256": hashlib.sha256(b"not really a model").hexdigest()}

    class Tiny:
        def __init__(self, value: float) -> None:
            self.value = value

        def to_arrays(self, prefix: str) -> dict:
            return {f"{prefix}w": np.full(3, self.value)}

    one = PoseModelSet({"box": Tiny(1.0)}, {"cache_key": "k"})
    same = PoseModelSet({"box": Tiny(1.0)})
    other = PoseModelSet({"box": Tiny(2.0)})
    a = provenance.pose_model_identity(one)
    assert a["cache_key"] == "k" and a["objects"] == ["box"]
    assert a["sha256"] == provenance.pose_model_identity(same)["sha256"]
    assert a["sha256"] != provenance.pose_model_identity(other)["sha256"]


def test_record_refuses_an_unknown_trainer():
    with pytest.raises(ValueError, match="trained_by must be one of"):
        provenance.record("magic", {}, None)


# --- the shipped policies ---------------------------------------------------------------------


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.parent.name)
def test_every_shipped_policy_says_how_it_was_trained(path):
    meta = json.loads(path.read_text())
    assert meta["trained_by"] in provenance.TRAINED_BY
    prov = meta["provenance"]
    assert {"command", "code", "data", "pose_models"} <= set(prov)
    for key in ("command", "code", "data"):
        assert prov[key], f"{key}: a value, or what is and is not recorded"
    if "not_recorded" not in prov:  # a complete record: trained since provenance existed
        assert prov["code"]["commit"] and prov["libraries"] and prov["recorded_at"]
        assert prov["code"]["uncommitted_changes"] is False
        return
    assert "not recorded" in json.dumps(prov), "what nobody wrote down is named, not invented"


def test_shipped_fine_tune_names_its_starting_policy():
    data = ROOT / "scorbot_gym" / "policies" / "data"
    finetuned = json.loads((data / "imitation_rlpd_oracle" / "policy.json").read_text())
    assert finetuned["trained_by"] == "rl_finetune"
    assert finetuned["provenance"]["data"]["init_policy"]["name"] == "learned"
    residual = json.loads((data / "residual_sac_oracle" / "policy.json").read_text())
    assert residual["trained_by"] == "residual" and residual["provenance"]["pose_models"] is None


def test_the_shipped_from_scratch_policy_saw_no_controller_and_says_which_checkpoint_it_is():
    """``rl_scratch``: SAC with no residual base and no demonstrations, the checkpoint its run
    chose on training-evaluation seeds (never a reported range), and it acts on its own env."""
    from scorbot_gym import make_env
    from scorbot_gym.policies.loading import load_policy, uses_scripted_controller
    from scorbot_gym.seeds import TRAINING_EVALUATION

    policy = load_policy("rl_scratch")
    meta = policy.meta
    assert meta["trained_by"] == "rl_from_scratch" and not uses_scripted_controller(policy)
    assert meta["saw_scripted_controller"] == {"residual_base": False, "bc_demo_episodes": 0}
    assert meta["config"]["bc_demos"] == 0 and meta["config"]["init_policy"] is None
    assert policy.object_features == "grasp_frame"
    chosen = meta["checkpoint"]
    assert chosen["kind"] == "best"
    assert chosen["evaluation"]["timesteps"] == meta["trained_timesteps"]
    seeds = chosen["evaluation_seeds"]
    assert seeds["first"] in TRAINING_EVALUATION and seeds["last"] in TRAINING_EVALUATION
    kwargs = dict(policy.env_kwargs())
    env = make_env(kwargs.pop("env_id"), pose="oracle", **kwargs)
    try:
        policy.bind(env)
        obs, info = env.reset(seed=3)
        policy.reset(obs, info)
        for _ in range(3):
            action = policy.act(obs)
            assert env.action_space.contains(action)
            obs, *_ = env.step(action)
    finally:
        env.close()


# --- Minari datasets --------------------------------------------------------------------------


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    import os

    from scorbot_gym.rl.datasets import record_demonstrations

    path = tmp_path_factory.mktemp("minari")
    old = os.environ.get("MINARI_DATASETS_PATH")
    os.environ["MINARI_DATASETS_PATH"] = str(path)
    try:
        record_demonstrations(
            "scorbot/prov-v0", episodes=2, dart_sigma=0.1, objects=["box"], seed=None
        )
        yield "scorbot/prov-v0"
    finally:
        if old is None:
            os.environ.pop("MINARI_DATASETS_PATH")
        else:
            os.environ["MINARI_DATASETS_PATH"] = old


def test_a_dataset_recovers_its_environment(dataset):
    import minari

    ds = minari.load_dataset(dataset)
    assert ds.spec.env_spec.id == "ScorbotGraspCartesian-v0"
    env = ds.recover_environment()
    try:
        assert env.observation_space == ds.observation_space
        obs, _ = env.reset(seed=seeds.DEMONSTRATIONS.start)
        first = next(ds.iterate_episodes())
        for key in ("joint_pos", "object_pos", "object_quat"):
            np.testing.assert_allclose(obs[key], first.observations[key][0], atol=1e-9)
        env.step(env.action_space.sample())
    finally:
        env.close()


def test_a_dataset_records_its_settings(dataset):
    from scorbot_gym.rl.datasets import read_dataset

    demos = read_dataset(dataset)
    s = demos.settings
    assert (s["action_type"], s["pose"], s["dart_sigma"], s["episodes"]) == (
        "cartesian",
        "oracle",
        0.1,
        2,
    )
    assert s["seeds"]["first"] == seeds.DEMONSTRATIONS.start and s["seeds"]["range"] == (
        "demonstrations"
    )
    assert s["dataset_id"] == dataset and len(s["sha256"]) == 64
    assert s["pose_models"] is None and s["code"]["version"] == "0.1.0"


def test_the_trainer_refuses_a_dataset_of_another_action_type(dataset):
    from scorbot_gym.rl.datasets import read_dataset

    joint = make_env("ScorbotGrasp-v0", pose="oracle", objects=["box"])
    try:
        with pytest.raises(ValueError) as exc:
            train_imitation(joint, TINY, read_dataset(dataset))
    finally:
        joint.close()
    msg = str(exc.value)
    assert len(msg.splitlines()) == 1
    assert "holds cartesian actions but the env takes joint actions" in msg


def test_a_policy_from_a_dataset_records_the_datasets_settings(dataset, box_env):
    from scorbot_gym.rl.datasets import read_dataset

    demos = read_dataset(dataset)
    policy, record = train_imitation(box_env, TINY, demos)
    assert record["config"]["demos"] == 2 and record["config"]["dart_sigma"] == 0.1
    assert TINY.dart_sigma == 0.2, "not the trainer's default"
    source = policy.meta["provenance"]["data"]["demonstrations"]
    assert source["kind"] == "dataset" and source["dataset_id"] == dataset
    assert source["sha256"] == demos.settings["sha256"] and source["episodes"] == 2


def test_demonstrations_on_evaluation_seeds_are_warned_about(tmp_path, monkeypatch):
    from scorbot_gym.rl.datasets import record_demonstrations

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    with pytest.warns(UserWarning, match="overlap the evaluation range 'test'"):
        record_demonstrations("scorbot/on-test-v0", episodes=1, seed=50_000, objects=["box"])


# --- benchmark outputs ------------------------------------------------------------------------


def test_outputs_default_to_a_fresh_run_folder_and_refuse_existing_files(tmp_path):
    out = Outputs("bench", root=tmp_path)
    first = out.path(None, "bench.json")
    assert first.parent.parent == tmp_path and first.parent.name.startswith("bench-")
    assert not first.parent.exists(), "made by the writer, not here"
    first.parent.mkdir()
    assert Outputs("bench", root=tmp_path).path(None, "x.json").parent != first.parent
    named = tmp_path / "r.json"
    assert out.path(named, "bench.json") == named
    companion(named, ".png").write_text("old figure")
    with pytest.raises(ValueError, match="r.png exists; add --overwrite"):
        out.path(named, "bench.json", companions=[".png"])
    named.write_text("{}")
    with pytest.raises(ValueError, match="--json .*r.json exists"):
        out.path(named, "bench.json", "--json")
    assert Outputs("bench", overwrite=True).path(named, "bench.json") == named
    assert companion(Path("a/x.json.gz"), ".png") == Path("a/x.png")


@pytest.mark.slow
def test_learned_policy_benchmark_never_replaces_the_shipped_policy(tmp_path, monkeypatch, capsys):
    """By default it trains into runs/learned_policy-<time>/; a named existing folder or
    result is refused, before any training, unless --overwrite."""
    from scorbot_gym.policies.imitation import SHIPPED_LEARNED_POLICY

    before = provenance.folder_sha256(SHIPPED_LEARNED_POLICY)
    bench = runpy.run_path(str(ROOT / "benchmarks" / "learned_policy.py"), run_name="t")["main"]
    monkeypatch.chdir(tmp_path)
    for argv, message in [
        (["--out", str(SHIPPED_LEARNED_POLICY)], "exists; add --overwrite"),
        (["--json", str(ROOT / "benchmarks/results/learned_policy.json")], "--json"),
        (["--skip-training"], "--skip-training evaluates --out"),
    ]:
        with pytest.raises(SystemExit) as exc:
            bench(argv)
        assert exc.value.code == 2 and message in capsys.readouterr().err
    tiny = ["--demos", "1", "--dagger-rounds", "0", "--fit-steps", "5", "--episodes", "1"]
    bench(tiny)
    (run,) = (tmp_path / "runs").iterdir()
    assert run.name.startswith("learned_policy-")
    result = json.loads((run / "learned_policy.json").read_text())
    assert result["trained_by"] == "imitation"
    assert Path(result["policy"]).resolve() == (run / "policy").resolve()
    meta = json.loads((run / "policy" / "policy.json").read_text())
    assert meta["provenance"]["command"] == sys.argv
    assert provenance.folder_sha256(SHIPPED_LEARNED_POLICY) == before


def test_learned_policy_benchmark_refuses_a_joint_dataset_while_parsing(
    tmp_path, monkeypatch, capsys
):
    from scorbot_gym.rl.datasets import record_demonstrations

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "minari"))
    monkeypatch.chdir(tmp_path)
    record_demonstrations("scorbot/joint-v0", episodes=1, env_id="ScorbotGrasp-v0", objects=["box"])
    bench = runpy.run_path(str(ROOT / "benchmarks" / "learned_policy.py"), run_name="t")["main"]
    with pytest.raises(SystemExit) as exc:
        bench(["--dataset", "scorbot/joint-v0"])
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert exc.value.code == 2 and "holds joint actions" in err
    assert not (tmp_path / "runs").exists(), "refused before anything was written"


def test_learned_policy_benchmark_refuses_unknown_training_objects_while_parsing(
    tmp_path, monkeypatch, capsys
):
    monkeypatch.chdir(tmp_path)
    bench = runpy.run_path(str(ROOT / "benchmarks" / "learned_policy.py"), run_name="t")["main"]
    with pytest.raises(SystemExit) as exc:
        bench(["--objects", "catalogue,heldout:nope"])
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert exc.value.code == 2 and "unknown held-out group 'nope'" in err
    with pytest.raises(SystemExit) as exc:
        bench(["--objects", "spoon"])
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "--objects: unknown 'spoon'; valid: catalogue, heldout:heading" in err
    assert not (tmp_path / "runs").exists(), "refused before anything was written"
