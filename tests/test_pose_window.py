"""The learned policy's memory of its fresh pose estimates (``HistorySpec.pose_window``): what
enters the window, what its summary says, and that policies with and without it load."""

from __future__ import annotations

from dataclasses import asdict

import numpy as np
import pytest

from scorbot_gym.policies.imitation import (
    N_POSE_DISPERSION_FEATURES,
    N_POSE_WINDOW_FEATURES,
    SHIPPED_LEARNED_POLICY,
    ActionHistory,
    HistorySpec,
    ImitationPolicy,
    n_features,
)

OPEN = np.array([0, 0, 0, 0, 0, 1.0], np.float32)


def _obs(x: float = 0.3, yaw: float = 0.0, valid: float = 1.0, age: float = 0.0) -> dict:
    return {
        "joint_pos": np.zeros(5),
        "ee_pos": np.array([0.2, 0.0, 0.3]),
        "object_pos": np.array([x, 0.0, 0.02]),
        "object_quat": np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)]),
        "pose_valid": np.array([valid]),
        "pose_age": np.array([age]),
    }


def test_only_fresh_estimates_enter_the_window_and_it_keeps_the_last_n():
    history = ActionHistory(HistorySpec(pose_window=3, pose_dispersion=True))
    assert np.all(history.pose_features(_obs(valid=0.0, age=1000.0)) == 0.0)  # none yet
    history.push(OPEN, _obs(x=0.1))
    history.push(OPEN, _obs(x=9.0, valid=0.0, age=3.0))  # lost: held, not new
    history.push(OPEN, _obs(x=9.0, age=2.0))  # valid but held between estimates
    assert [p[0] for p, _ in history.estimates] == [0.1]
    for x in (0.2, 0.3, 0.4):
        history.push(OPEN, _obs(x=x))
    assert [p[0] for p, _ in history.estimates] == [0.2, 0.3, 0.4]
    f = history.pose_features(_obs(x=0.5))  # the current estimate counts, the oldest leaves
    assert f[0] == 1.0 and f[1] == pytest.approx(0.4)  # full window, mean x of 0.3, 0.4, 0.5
    assert f[4] == pytest.approx(0.4 - 0.2)  # mean minus the TCP
    assert f[-1] == pytest.approx(np.sqrt(2 / 3) * 0.1)  # RMS spread of the three


def test_headings_average_on_the_doubled_circle():
    """A parallel gripper closes along the same line after a half turn: estimates at +89 and
    -89 degrees agree (mean 90), they do not cancel to 0."""
    history = ActionHistory(HistorySpec(pose_window=4, pose_dispersion=True))
    history.push(OPEN, _obs(yaw=np.radians(89)))
    f = history.pose_features(_obs(yaw=np.radians(-89)))
    sin2, cos2 = f[7], f[11]  # the first of the four angles: the heading itself
    assert np.degrees(0.5 * np.arctan2(sin2, cos2)) % 180 == pytest.approx(90.0, abs=1e-6)
    assert f[15] == pytest.approx(1.0, abs=1e-3)  # resultant length: they agree


def test_a_window_needs_the_observation_and_reset_empties_it():
    history = ActionHistory(HistorySpec(pose_window=2))
    with pytest.raises(ValueError, match="pose_window"):
        history.push(OPEN)
    history.push(OPEN, _obs())
    history.reset()
    assert history.estimates == []
    assert ActionHistory(HistorySpec()).pose_features(_obs()).shape == (0,)  # no window
    with pytest.raises(ValueError, match="pose_window"):
        HistorySpec(pose_window=-1)


def _random_policy(meta: dict, n: int, seed: int = 0) -> ImitationPolicy:
    from scorbot_gym.policies.imitation import MLP

    rng = np.random.default_rng(seed)
    net = MLP([rng.normal(size=(n, 4)), rng.normal(size=(4, 6))], [np.zeros(4), np.zeros(6)])
    return ImitationPolicy(net, np.zeros(n), np.ones(n), meta)


def test_policies_with_and_without_a_window_save_and_load(tmp_path):
    shipped = ImitationPolicy.load(SHIPPED_LEARNED_POLICY)
    n_classes = len(shipped.classes)
    # a policy.json as written before pose_window existed: no window, no dispersion key
    before = {**shipped.meta, "history": {"previous_actions": 2, "gripper_commands": 20}}
    _random_policy(before, n_features(n_classes, HistorySpec())).save(tmp_path / "old")
    old = ImitationPolicy.load(tmp_path / "old")
    assert old.history_spec == HistorySpec()
    spec = HistorySpec(pose_window=8)
    n = n_features(n_classes, spec)
    assert n == n_features(n_classes, HistorySpec()) + N_POSE_WINDOW_FEATURES
    meta = {**shipped.meta, "history": asdict(spec)}
    _random_policy(meta, n).save(tmp_path / "p")
    loaded = ImitationPolicy.load(tmp_path / "p")
    assert loaded.history_spec == spec
    with pytest.raises(ValueError, match="incompatible policy"):  # window without its features
        ImitationPolicy(old.net, old.mean, old.std, meta)
    # written when the window always had its dispersion values: loads with them
    windowed = {**shipped.meta, "history": {**before["history"], "pose_window": 8}}
    _random_policy(windowed, n + N_POSE_DISPERSION_FEATURES).save(tmp_path / "w")
    assert ImitationPolicy.load(tmp_path / "w").history_spec.pose_dispersion


def test_dispersion_is_optional_and_old_records_keep_it():
    """Without ``pose_dispersion`` the summary stops before the agreement and spread values
    (the rest identical); a ``policy.json`` written before the option existed had them."""
    obs = [_obs(x=0.1, yaw=0.2), _obs(x=0.2, yaw=-0.1), _obs(x=0.4, yaw=0.1)]
    plain, full = (
        ActionHistory(HistorySpec(pose_window=3, pose_dispersion=d)) for d in (False, True)
    )
    for history in (plain, full):
        for o in obs[:-1]:
            history.push(OPEN, o)
    f_plain, f_full = plain.pose_features(obs[-1]), full.pose_features(obs[-1])
    assert len(f_plain) == N_POSE_WINDOW_FEATURES
    assert len(f_full) == N_POSE_WINDOW_FEATURES + N_POSE_DISPERSION_FEATURES
    np.testing.assert_array_equal(f_plain, f_full[:N_POSE_WINDOW_FEATURES])
    assert HistorySpec.from_record({"pose_window": 8}).pose_dispersion
    assert not HistorySpec.from_record({"pose_window": 0}).pose_dispersion
    assert not HistorySpec.from_record({"pose_window": 8, "pose_dispersion": False}).pose_dispersion
    with pytest.raises(ValueError, match="pose_dispersion needs a pose_window"):
        HistorySpec(pose_dispersion=True)
    with pytest.raises(ValueError, match="pose_dispersion must be a bool"):
        HistorySpec(pose_window=2, pose_dispersion=1)
    with pytest.raises(ValueError, match="unexpected keyword"):
        HistorySpec.from_record({"pose_window": 2, "window": 3})
    shipped = ImitationPolicy.load(SHIPPED_LEARNED_POLICY)  # loads with its recorded features
    assert shipped.net.n_inputs == n_features(len(shipped.classes), shipped.history_spec)
