"""The image-blind pose sources (``constant``, ``oracle_position``): the closed loop's blind arms,
each named for what it ignores, are a pose source swapped by name, and answer what they say:
one pose whatever the scene, or the true position with that same rotation."""

from __future__ import annotations

import numpy as np
import pytest

from scorbot_gym.envs.factory import make_env
from scorbot_gym.evaluation.rollout import RolloutConfig, run_rollout
from scorbot_gym.objects import get_object
from scorbot_gym.perception import ConstantPoseSource, make_pose_source
from scorbot_gym.perception.base import PerceptionFrame
from scorbot_gym.perception.constant import WORKSPACE_CENTRE
from scorbot_gym.sim.scene import TABLE_HEIGHT, WORKSPACE_X, WORKSPACE_Y
from scorbot_gym.sim.simulation import quat_to_mat

TRUTH = {"position": [0.31, -0.07, 0.9], "quaternion": [0.0, 0.0, 0.0, 1.0]}


def _lowest_z(name: str, position, quaternion) -> float:
    verts = get_object(name).mesh_vertices() @ quat_to_mat(np.asarray(quaternion)).T
    return float(verts[:, 2].min() + position[2])


@pytest.mark.parametrize("name", ["banana", "box", "large_marker"])
def test_constant_rests_the_named_object_at_the_centre_of_the_placement_region(name):
    source = make_pose_source("constant")
    assert not source.privileged and source.required_keys == ()
    est = source.estimate(PerceptionFrame(object_name=name))
    assert est.valid and est.object_name == name
    assert WORKSPACE_CENTRE == (np.mean(WORKSPACE_X), np.mean(WORKSPACE_Y))
    np.testing.assert_allclose(est.position[:2], WORKSPACE_CENTRE)
    # on the table, on its first resting face, heading 0
    assert _lowest_z(name, est.position, est.quaternion) == pytest.approx(TABLE_HEIGHT, abs=1e-3)
    np.testing.assert_allclose(est.quaternion, get_object(name).resting_quats[0], atol=1e-12)
    # the same answer whatever the truth and at every step: it reads neither
    again = source.estimate(PerceptionFrame(object_name=name, truth=TRUTH, step=7))
    np.testing.assert_array_equal(again.position, est.position)
    np.testing.assert_array_equal(again.quaternion, est.quaternion)


def test_oracle_position_reads_the_true_position_and_nothing_else():
    source = make_pose_source("oracle_position", yaw_deg=90.0)
    assert source.privileged  # recorded as privileged, and the wrapper hands it the truth
    est = source.estimate(PerceptionFrame(object_name="box", truth=TRUTH))
    np.testing.assert_array_equal(est.position, TRUTH["position"])
    np.testing.assert_allclose(est.quaternion, [np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)])


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"position": "middle"}, "position must be one of"),
        ({"position": (0.3, 0.1, 0.2)}, "a finite \\(x, y\\)"),
        ({"yaw_deg": float("nan")}, "yaw_deg must be a finite"),
        ({"resting_index": -1}, "resting_index must be an int >= 0"),
    ],
)
def test_bad_arguments_are_one_line_errors(kwargs, message):
    with pytest.raises(ValueError, match=message) as err:
        ConstantPoseSource(**kwargs)
    assert "\n" not in str(err.value)


def test_without_the_identity_the_blind_sources_say_what_to_give():
    with pytest.raises(ValueError, match="identity='given'") as err:
        make_pose_source("constant").reset(PerceptionFrame(), np.random.default_rng(0))
    assert "\n" not in str(err.value)
    with pytest.raises(ValueError, match="drop recognize"):
        RolloutConfig(pose="constant", recognize=True)


def test_the_env_renders_nothing_for_a_blind_source_and_observes_its_answer():
    env = make_env(pose="constant", objects=["box"])
    try:
        obs, info = env.reset(seed=5)
        assert not any(k.endswith("_rgb") for k in obs)  # no camera: nothing to look at
        np.testing.assert_allclose(obs["object_pos"][:2], WORKSPACE_CENTRE)
        assert info["perception"]["source"] == "constant" and info["perception"]["valid"]
        assert not info["perception"]["privileged"]
        true_xy = np.asarray(info["object_pose"]["position"])[:2]
        assert info["perception"]["pos_err_cm"] == pytest.approx(
            100 * np.linalg.norm(true_xy - WORKSPACE_CENTRE), abs=0.5
        )
    finally:
        env.close()


@pytest.mark.slow
def test_blind_arms_run_episodes_and_record_their_source():
    """A couple of seeded episodes per blind arm (the closed-loop benchmark's configurations)."""
    for pose in ("constant", "oracle_position"):
        summary, results = run_rollout(RolloutConfig(pose=pose, episodes=2, seed=1000))
        assert summary["episodes"] == 2 and summary["pose_source"] == pose
        assert summary["config"]["pose"] == pose and len(results) == 2
        assert summary["perception"]["valid_rate"] == 1.0
