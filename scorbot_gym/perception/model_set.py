"""Pose from a camera image with trained per-object models (``manifold`` and its baselines).

The source segments the object in its camera's image, takes the object's identity (given, or
recognised), runs that object's estimator from a :class:`pose.model_set.PoseModelSet` and
converts the camera-frame answer to the world frame with the camera's public calibration.
"""

from __future__ import annotations

import os
import time

import numpy as np

from pose.model_set import PoseModelSet
from pose.view import View
from scorbot_gym.perception.base import PerceptionFrame, WorldPose
from scorbot_gym.perception.segmenters import PrivilegedSegmenter, Segmenter
from scorbot_gym.sim.simulation import mat_to_quat


class ModelSetPoseSource:
    """Estimate the pose with a trained :class:`PoseModelSet` on one camera's images.

    ``models`` is a model set or the path of a file from ``scorbot-gym pose train``; its
    ``meta`` names the camera and image size it was trained for, and the env must render that
    camera at that size (``cameras=[camera], image_width=..., image_height=...``).
    """

    def __init__(
        self,
        models: PoseModelSet | str | os.PathLike,
        segmenter: Segmenter | None = None,
    ) -> None:
        self.models = models if isinstance(models, PoseModelSet) else PoseModelSet.load(models)
        meta = self.models.meta
        self.camera = str(meta.get("camera", "top"))
        self.width, self.height = int(meta.get("width", 640)), int(meta.get("height", 480))
        self.segmenter = segmenter if segmenter is not None else PrivilegedSegmenter()

    @property
    def privileged(self) -> bool:
        return self.segmenter.privileged

    @property
    def required_keys(self) -> tuple[str, ...]:
        return (f"{self.camera}_rgb", *self.segmenter.required_keys(self.camera))

    @property
    def env_requirements(self) -> dict:
        """The env keyword arguments that make it render what this source reads."""
        return {
            "cameras": [self.camera],
            "image_width": self.width,
            "image_height": self.height,
            "image_types": ["rgb", *self.segmenter.image_types],
        }

    def reset(self, frame: PerceptionFrame, rng: np.random.Generator) -> None:
        self.segmenter.reset(frame, self.camera)

    def estimate(self, frame: PerceptionFrame) -> WorldPose:
        cam_name = self.camera
        t0 = time.perf_counter()
        mask = self.segmenter.segment(frame, cam_name)
        timings = {"segment": (time.perf_counter() - t0) * 1e3}
        name = frame.object_name
        if mask is None:
            return WorldPose.invalid("no object in view", object_name=name, timings_ms=timings)
        if name is None and len(self.models.object_names) == 1:
            name = self.models.object_names[0]
        if name is None:
            raise ValueError(
                "ModelSetPoseSource needs the object's identity (frame.object_name) when its "
                f"model set holds several objects ({self.models.object_names})"
            )
        cam = frame.cameras[cam_name]
        image = np.asarray(frame.observation[f"{cam_name}_rgb"])
        est = self.models.predict(View(image, cam, mask, name))
        timings.update({f"estimate_{k}": v for k, v in est.timings_ms.items() if k != "total"})
        timings["estimate"] = est.timings_ms.get("total", 0.0)
        common = dict(
            object_name=name,
            n_keypoints=est.n_keypoints,
            n_inliers=est.n_inliers,
            timings_ms=timings,
            camera=cam_name,
        )
        if not est.valid:
            return WorldPose.invalid(est.reason, **common)
        T = cam.world_from_camera
        R_world = T[:3, :3] @ est.rotation
        t_world = T[:3, :3] @ est.translation + T[:3, 3]
        return WorldPose(t_world, mat_to_quat(R_world), True, est.confidence, **common)
