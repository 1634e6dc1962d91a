"""From a camera view to the pose a controller grasps at (simulator -> views -> estimator).

The object mask comes from the simulator's segmentation, standing in for background
subtraction against the empty table, which a fixed eye-to-hand camera makes easy. The object's
identity is given (``info["object_name"]``); ``pose.pipeline.RecognizeThenEstimate`` can supply
it from the silhouette instead.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import gymnasium as gym
import numpy as np

from pose.metrics import rotation_error_deg
from pose.model_set import PoseModelSet
from pose.view import PoseEstimate, View
from scorbot_gym.controllers import ObjectPose2D
from scorbot_gym.objects import get_object
from scorbot_gym.sim.simulation import quat_to_mat


@dataclass
class PerceivedPose:
    pose: ObjectPose2D | None  # None when the estimator found no usable view
    estimate: PoseEstimate | None = None  # None for the oracle
    position_error_m: float | None = None  # against the ground truth, for reports
    rotation_error_deg: float | None = None  # symmetry-aware


def yaw_from_quat(q: np.ndarray) -> float:
    """Heading about world z of a (w, x, y, z) quaternion."""
    w, x, y, z = q
    return float(np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))


def oracle_pose(env: gym.Env, info: dict) -> PerceivedPose:
    """The ground-truth pose from ``info`` (the upper bound for any estimator)."""
    pose = info["object_pose"]
    return PerceivedPose(
        ObjectPose2D(np.asarray(pose["position"]), yaw_from_quat(pose["quaternion"]))
    )


class ManifoldPoseSource:
    """Estimates the object's pose with a trained :class:`pose.model_set.PoseModelSet`.

    The view is rendered from the camera and at the size the model file was trained with.
    """

    def __init__(self, models: PoseModelSet | str | os.PathLike) -> None:
        self.models = models if isinstance(models, PoseModelSet) else PoseModelSet.load(models)
        meta = self.models.meta
        self.camera = str(meta.get("camera", "top"))
        self.width, self.height = int(meta.get("width", 640)), int(meta.get("height", 480))

    def __call__(self, env: gym.Env, info: dict) -> PerceivedPose:
        sim = env.unwrapped.sim
        name = info["object_name"]
        cam = sim.camera_model(self.camera, self.width, self.height)
        image = sim.render(self.camera, "rgb", self.width, self.height)
        mask = sim.render(self.camera, "segmentation", self.width, self.height)
        est = self.models.predict(View(image, cam, mask, name))
        gt_pos = np.asarray(info["object_pose"]["position"])
        gt_R = quat_to_mat(info["object_pose"]["quaternion"])
        if not est.valid:
            return PerceivedPose(None, est)
        world_R = cam.world_from_camera[:3, :3] @ est.rotation
        world_t = cam.world_from_camera[:3, :3] @ est.translation + cam.world_from_camera[:3, 3]
        yaw = float(np.arctan2(world_R[1, 0], world_R[0, 0]))
        return PerceivedPose(
            ObjectPose2D(world_t, yaw),
            est,
            float(np.linalg.norm(world_t - gt_pos)),
            rotation_error_deg(world_R, gt_R, get_object(name).symmetry),
        )
