"""How long the TCP has been still (``HistorySpec.stall_steps``): the learned policy's stand-in
for the scripted controller's descent timer, computed from its own observations only."""

from __future__ import annotations

import numpy as np
import pytest

from scorbot_gym.policies.imitation import (
    STILL_M,
    ActionHistory,
    HistorySpec,
    n_features,
    n_history_features,
)
from scorbot_gym.policies.pixel import n_vector_features

DOWN = np.array([0, 0, -1, 0, 0, 1.0], np.float32)


def _obs(z: float) -> dict:
    return {"ee_pos": np.array([0.3, 0.0, z])}


def test_the_count_rises_while_the_tcp_is_still_and_drops_when_it_moves():
    history = ActionHistory(HistorySpec(previous_actions=0, gripper_commands=0, stall_steps=4))
    assert history.features().tolist() == [0.0]
    history.push(DOWN, _obs(0.30))  # the first observation: nothing to compare with
    assert history.features()[-1] == 0.0
    for k in range(1, 7):  # blocked: commanding down, the TCP stays (under 1 mm a step)
        history.push(DOWN, _obs(0.30 - 0.4 * STILL_M * (k % 2)))
        assert history.features()[-1] == pytest.approx(min(k, 4) / 4)
    history.push(DOWN, _obs(0.29))  # it moved 1 cm: moving again
    assert history.features()[-1] == 0.0
    history.reset()
    assert history.still_steps == 0 and history.features()[-1] == 0.0
    with pytest.raises(ValueError, match="stall_steps"):
        history.push(DOWN)


def test_the_feature_is_optional_and_old_records_go_without_it():
    plain, stall = HistorySpec(), HistorySpec(stall_steps=50)
    assert n_history_features(stall) == n_history_features(plain) + 1
    assert n_features(11, stall) == n_features(11, plain) + 1
    assert n_vector_features(11, stall) == n_vector_features(11, plain) + 1
    assert HistorySpec.from_record({"previous_actions": 2, "gripper_commands": 20}) == plain
    assert len(ActionHistory(plain).features()) == n_history_features(plain)
    with pytest.raises(ValueError, match="stall_steps must be an int >= 0"):
        HistorySpec(stall_steps=-1)
