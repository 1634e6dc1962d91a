"""The resting hypothesis of the model-set source (``ModelSetPoseSource(resting_models=...)``):
where the primary models answer a near-resting pose, the resting models' estimate on the same
view is kept; a tilted answer stays the primary models'. The images, masks and cameras are the
env's own (top camera, background subtraction); the two model sets are stand-ins that answer a
fixed world pose, so each test knows which hypothesis the source kept."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import scorbot_gym  # noqa: F401  (registers the envs)
from pose.camera import CameraModel
from pose.model_set import PoseModelSet
from pose.view import PoseEstimate, View
from scorbot_gym.evaluation.rollout import RolloutConfig
from scorbot_gym.objects import get_object
from scorbot_gym.perception.base import PerceptionFrame
from scorbot_gym.perception.model_set import ModelSetPoseSource
from scorbot_gym.perception.support import TableSupport
from scorbot_gym.sim.scene import TABLE_HEIGHT
from scorbot_gym.sim.simulation import quat_from_yaw, quat_mul, quat_to_mat

META = {"camera": "top", "width": 80, "height": 60}


class _Answers:
    """An estimator that answers one world pose (``None``: invalid), through the view's
    camera, and counts its calls."""

    def __init__(self, R_world: np.ndarray | None, t_world: np.ndarray | None = None):
        self.R_world, self.t_world, self.calls = R_world, t_world, 0

    def predict(self, view: View) -> PoseEstimate:
        self.calls += 1
        if self.R_world is None:
            return PoseEstimate.invalid("no match", {})
        T = view.camera.world_from_camera
        R = T[:3, :3].T @ self.R_world
        t = T[:3, :3].T @ (self.t_world - T[:3, 3])
        return PoseEstimate(R, t, 1.0, True, {"total": 0.1}, n_keypoints=20, n_inliers=12)


def _resting(yaw: float, tilt_deg: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """The box at heading ``yaw`` on its first resting face, tilted ``tilt_deg`` about the
    world x axis, and its position on the table near the workspace centre."""
    spec = get_object("box")
    R = quat_to_mat(quat_mul(quat_from_yaw(yaw), np.asarray(spec.resting_quats[0], float)))
    a = np.radians(tilt_deg)
    R = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]]) @ R
    z = TABLE_HEIGHT - float((spec.mesh_vertices() @ R[2]).min())
    return R, np.array([0.3, 0.0, z])


@pytest.fixture(scope="module")
def scene():
    """One reset of the env at the stand-ins' size: the observation, cameras, backgrounds."""
    source = ModelSetPoseSource(PoseModelSet({"box": _Answers(None)}, META))
    env = gym.make("ScorbotGrasp-v0", objects=["box"], **source.env_requirements)
    obs, info = env.reset(seed=0)
    env.close()
    cameras = {c: CameraModel(**p) for c, p in info["camera_params"].items()}
    return PerceptionFrame(obs, cameras, "box", backgrounds=info["camera_background"])


def _estimate(frame: PerceptionFrame, primary: _Answers, resting: _Answers):
    source = ModelSetPoseSource(
        PoseModelSet({"box": primary}, META),
        support="none",
        resting_models=PoseModelSet({"box": resting}, META),
    )
    source.reset(frame, np.random.default_rng(0))
    return source.estimate(frame)


def test_a_near_resting_answer_is_replaced_by_the_resting_models(scene):
    R_prim, t = _resting(0.4, tilt_deg=3.0)
    R_rest, t_rest = _resting(0.5)
    primary, resting = _Answers(R_prim, t + [0, 0, 0.004]), _Answers(R_rest, t_rest)
    pose = _estimate(scene, primary, resting)
    assert pose.valid and pose.details["hypothesis"] == "resting"
    assert np.allclose(pose.rotation, R_rest, atol=1e-6)
    assert np.allclose(pose.position, t_rest, atol=1e-6)
    assert resting.calls == 1 and pose.timings_ms["estimate_resting"] >= 0.0


def test_a_tilted_answer_keeps_the_primary_models_estimate(scene):
    R_prim, t = _resting(0.4, tilt_deg=20.0)
    primary, resting = _Answers(R_prim, t), _Answers(*_resting(0.5))
    pose = _estimate(scene, primary, resting)
    assert np.allclose(pose.rotation, R_prim, atol=1e-6)
    assert np.allclose(pose.position, t, atol=1e-6)
    assert resting.calls == 0 and "hypothesis" not in pose.details


def test_an_invalid_resting_answer_keeps_the_primary_estimate(scene):
    R_prim, t = _resting(0.4, tilt_deg=2.0)
    pose = _estimate(scene, _Answers(R_prim, t), _Answers(None))
    assert pose.valid and pose.details["hypothesis"] == "primary"
    assert np.allclose(pose.position, t, atol=1e-6)


def test_the_resting_test_is_the_table_priors():
    R, t = _resting(1.0, tilt_deg=4.0)
    from scorbot_gym.perception.base import WorldPose
    from scorbot_gym.sim.simulation import mat_to_quat

    pose = WorldPose(t, mat_to_quat(R), True, object_name="box")
    assert TableSupport().is_resting(pose)
    assert not TableSupport(snap_deg=3.0).is_resting(pose)
    assert not TableSupport().is_resting(WorldPose.invalid("none", object_name="box"))


def test_mismatched_resting_models_and_configs_give_one_line_errors():
    models = PoseModelSet({"box": _Answers(np.eye(3), np.zeros(3))}, META)
    for meta, objects in (({**META, "width": 320}, ["box"]), (META, ["box", "banana"])):
        other = PoseModelSet({o: _Answers(np.eye(3), np.zeros(3)) for o in objects}, meta)
        with pytest.raises(ValueError, match="resting_models must be a model set") as err:
            ModelSetPoseSource(models, resting_models=other)
        assert "\n" not in str(err.value)
    with pytest.raises(ValueError, match="resting_hypothesis adds"):
        RolloutConfig(pose="oracle", resting_hypothesis=True)
    with pytest.raises(ValueError, match="resting_hypothesis adds"):
        RolloutConfig(pose="manifold", pose_model="m.npz", resting_hypothesis=True)


@pytest.mark.slow
def test_the_config_gives_the_source_the_resting_view_models_and_the_spec_rebuilds_it():
    """``resting_hypothesis=True`` hands the resting-view default models (trained on first use)
    to the source, and ``gym.make(env.spec)`` rebuilds it with them."""

    def source(env):
        while not hasattr(env, "source"):
            env = env.env
        return env.source

    env = RolloutConfig(pose="manifold", resting_hypothesis=True).make_env()
    again = gym.make(env.spec)
    for built in (source(env), source(again)):
        assert built.resting_models is not None
        assert built.resting_models.meta["training"]["tilted_views"] == 0
        assert built.models.meta["training"]["tilted_views"] > 0
    env.close()
    again.close()
