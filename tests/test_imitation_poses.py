"""Imitation on estimated poses (``ImitationConfig.poses``: the learner sees a noisy or estimated
pose, the expert labels from the oracle) and ``compare``'s manifold condition with no
privileged input (issue 36, targets under the estimator and under pose noise)."""

from __future__ import annotations

import json
import re
from dataclasses import replace

import numpy as np
import pytest

from scorbot_gym.cli import main
from scorbot_gym.evaluation import chunks
from scorbot_gym.evaluation import compare as cmp
from scorbot_gym.policies.loading import load_policy
from scorbot_gym.policies.scripted import ScriptedGraspPolicy
from scorbot_gym.rl.imitation import (
    ExecutedActionExpert,
    ImitationConfig,
    learner_pose,
    make_learner_envs,
    oracle_view,
    train_imitation,
)

pytestmark = pytest.mark.rl

#: heavy noise and frequent loss, so that the learner's view visibly differs from the truth
NOISY = "noisy@0.05:30:0.5"
TINY = ImitationConfig(
    demos=2, dagger_rounds=1, dagger_episodes=2, fit_steps=20, hidden=(16,), poses=("oracle", NOISY)
)

TINY_ORACLE = replace(TINY, poses=("oracle",))


@pytest.fixture(scope="module")
def learner_envs():
    envs = make_learner_envs(TINY, objects=["box"])
    yield envs
    for env in envs:
        env.close()


def test_learner_pose_names_and_one_line_errors():
    assert learner_pose("oracle") == ("oracle", {}, "given")
    assert learner_pose("noisy@0.02:20:0.5") == (
        "noisy_oracle",
        {"pos_sigma_m": 0.02, "yaw_sigma_deg": 20.0, "dropout": 0.5},
        "given",
    )
    assert learner_pose("noisy@0.01")[1]["yaw_sigma_deg"] == 5.0  # compare's default pairing
    source, kwargs, identity = learner_pose("manifold")
    assert (source, identity) == ("manifold", "recognize")  # no privileged identity
    assert kwargs["segmenter"] == "background"  # nor privileged masks
    for bad in ("truth", "noisy@x", "noisy@0.01:5:2", "noisy@0.01:5:0.1:3"):
        with pytest.raises(ValueError, match="learner pose") as err:
            learner_pose(bad)
        assert "\n" not in str(err.value)
    with pytest.raises(ValueError, match="learner pose"):
        ImitationConfig(poses=("oracle", "truth"))  # checked before any episode
    with pytest.raises(ValueError, match="non-empty list"):
        ImitationConfig(poses="oracle")


def test_learner_sees_the_estimate_while_the_expert_labels_from_the_oracle(learner_envs, tmp_path):
    """Round-robin over the learner poses; in the noisy env the observed pose differs from the
    truth (and is sometimes lost), yet every label is the scripted controller's action on the
    oracle view of the same state; the trained policy records what it was trained on."""
    with pytest.raises(ValueError, match="one env per learner pose"):
        train_imitation(learner_envs[:1], TINY)
    fits = []
    policy, record = train_imitation(learner_envs, TINY, on_round=lambda p, r: fits.append(r))
    assert fits == record["rounds"]  # a checkpoint hook after BC and every DAgger round
    assert record["learner_poses"] == ["oracle", NOISY]
    assert set(record["rounds"][1]["success_by_pose"]) == {"oracle", NOISY}
    policy.save(tmp_path / "p")
    meta = json.loads((tmp_path / "p" / "policy.json").read_text())
    assert meta["training"]["config"]["poses"] == ["oracle", NOISY]
    assert load_policy(tmp_path / "p").bind(learner_envs[1]) is not None

    from scorbot_gym.rl.imitation import _collect_round_robin

    rng = np.random.default_rng(0)
    episodes = _collect_round_robin(
        learner_envs, [11, 12], learner=policy, beta=0.0, rng=rng, sync_expert=True
    )
    assert [ep.seed for ep in episodes] == [11, 12]
    oracle_ep, noisy_ep = episodes
    seen, true = oracle_ep.observations["object_pos"], oracle_ep.infos["object_position"]
    np.testing.assert_allclose(seen, true, atol=1e-9)  # the oracle learner sees the truth
    seen, true = noisy_ep.observations["object_pos"], noisy_ep.infos["object_position"]
    assert np.median(np.linalg.norm(seen[:, :2] - true[:, :2], axis=1)) > 0.01
    assert (noisy_ep.observations["pose_valid"] == 0).any()  # estimates lost, last one held

    env = learner_envs[1]
    classes = env.get_wrapper_attr("class_names")
    expert = ExecutedActionExpert(ScriptedGraspPolicy.for_env(env))
    for t in range(len(noisy_ep) + 1):
        obs = {k: v[t] for k, v in noisy_ep.observations.items()}
        info = {
            "object_pose": {
                "position": noisy_ep.infos["object_position"][t],
                "quaternion": noisy_ep.infos["object_quaternion"][t],
            },
            "object_name": classes[int(noisy_ep.infos["object_class"][t])],
        }
        if t == 0:
            expert.reset(oracle_view(obs, info, classes), info)
        np.testing.assert_array_equal(
            expert.act(oracle_view(obs, info, classes)), noisy_ep.labels[t]
        )
        if t < len(noisy_ep):
            expert.executed(noisy_ep.actions[t])


def test_manifold_condition_gives_the_estimator_no_privileged_input():
    (cond,) = cmp.pose_conditions(["manifold"], pose_model="models.npz")
    assert cond.identity == "recognize"
    assert cond.kwargs["segmenter"] == "background" and cond.kwargs["models"] == "models.npz"
    assert cond.kwargs["cameras"] == list(cmp.MANIFOLD_CAMERAS)
    oracle, noisy = cmp.pose_conditions(["oracle"], ["0:20"])
    assert (oracle.identity, noisy.identity) == ("given", "given")
    assert set(oracle.record()) == {
        "label", "source", "noise_pos_m", "noise_yaw_deg", "identity", "segmenter", "estimator"
    }  # fmt: skip
    assert oracle.record()["estimator"] is None and cond.record()["estimator"] == "manifold"
    assert all(re.search(rf"\b{k}\b", cmp.__doc__) for k in oracle.record())


@pytest.mark.slow
def test_compare_runs_the_manifold_arm_on_recognised_identity(tmp_path):
    """A real manifold arm (a small box model): the report says the identity was recognised
    and the masks were the background subtraction's, and the source read no ground truth."""
    model = tmp_path / "box.npz"
    argv = ["pose", "train", "--objects", "box", "--views", "108", "--width", "320"]
    argv += ["--height", "240", "--out", str(model), "--cache-dir", str(tmp_path), "--quiet"]
    assert main(argv) == 0
    report = cmp.compare(
        ["scripted"], ["manifold"], 1, seed=5, pose_model=model, objects=["box"], progress=False
    )
    (cond,) = report["conditions"]
    assert (cond["label"], cond["identity"], cond["segmenter"]) == (
        "manifold",
        "recognize",
        "background",
    )
    (rec,) = report["results"]
    assert rec["pose"] == "manifold" and rec["perception"]["privileged"] is False
    assert rec["perception"]["recognition_accuracy"] is not None  # identity was recognised


@pytest.mark.slow
def test_chunked_arms_give_the_same_episodes(monkeypatch):
    """Split into one-episode chunks over two processes: episode by episode the same results
    as one process running each arm whole."""
    monkeypatch.setattr(chunks, "MIN_CHUNK_EPISODES", 1)
    kw = dict(objects=["box"], noise=["0.02:20"], progress=False)
    whole = cmp.compare(["scripted", "learned"], ["oracle"], 3, seed=4, jobs=1, **kw)
    chunked = cmp.compare(["scripted", "learned"], ["oracle"], 3, seed=4, jobs=2, **kw)
    for a, b in zip(whole["results"], chunked["results"], strict=True):
        assert (a["policy"], a["pose"]) == (b["policy"], b["pose"])
        assert a["episode_success"] == b["episode_success"]
        assert a["steps_to_success"] == b["steps_to_success"]


@pytest.mark.slow
def test_fine_tuning_starts_from_a_saved_policy_and_counts_its_cost(learner_envs, tmp_path):
    """``init_policy``: the first fit starts from the saved network (fine-tuning it on
    estimated poses); the record's totals include what the starting policy cost."""
    base, base_record = train_imitation(learner_envs[0], TINY_ORACLE)
    base.save(tmp_path / "base")
    config = replace(TINY, init_policy=str(tmp_path / "base"), fit_steps=1, learning_rate=1e-9)
    tuned, record = train_imitation(learner_envs, config)
    for w_base, w_tuned in zip(base.net.weights, tuned.net.weights, strict=True):
        np.testing.assert_allclose(w_base, w_tuned, atol=1e-4)  # (almost) no step taken
    assert record["init_policy"]["env_steps"] == base_record["env_steps"]
    own = sum(r["env_steps"] for r in record["rounds"])
    assert record["env_steps"] == own + base_record["env_steps"]
    wider = replace(TINY, init_policy=str(tmp_path / "base"), hidden=(8,))
    with pytest.raises(ValueError, match="does not fit this run") as err:
        train_imitation(learner_envs, wider)
    assert "\n" not in str(err.value)


def test_features_before_the_first_estimate_do_not_set_the_normalisation(learner_envs):
    """Rows before any valid estimate hold placeholder zeros for the pose: AGE_FEATURE finds
    them, and the feature statistics come from the rows with an estimate."""
    from scorbot_gym.policies.imitation import AGE_FEATURE, ActionHistory
    from scorbot_gym.rl.imitation import _skeleton, fit_policy

    policy = _skeleton(learner_envs[0], TINY)
    obs, _ = learner_envs[0].reset(seed=0)
    history = ActionHistory(policy.history_spec)
    fresh = policy.features(obs, history)
    assert fresh[AGE_FEATURE] == 0.0  # the oracle: estimated at once
    never = policy.features(
        {**obs, "pose_age": np.array([1000.0]), "object_pos": np.zeros(3)}, history
    )
    assert never[AGE_FEATURE] == 1.0
    rng = np.random.default_rng(0)
    estimated = fresh + rng.normal(0, 0.01, (50, len(fresh)))
    feats = np.vstack([estimated, np.repeat(never[None], 10, axis=0)]).astype(np.float32)
    labels = np.zeros((len(feats), 6), np.float32)
    fit_policy(policy, feats, labels, replace(TINY, fit_steps=1), seed=0)
    np.testing.assert_allclose(policy.mean, estimated.mean(axis=0), atol=1e-5)
