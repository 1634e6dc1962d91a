"""What a pose source sees and what it answers, in the world frame.

A pose source turns one step's camera images (with the cameras' public calibration) into an
object pose in the world frame. Sources that need the ground truth (the oracle family) say so
with ``privileged = True``: only they receive it, and everything they answer is marked as such
in the experiment records. Everything else gets images, camera models and proprioception only.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

from pose.camera import CameraModel
from scorbot_gym.sim.simulation import quat_to_mat


@dataclass
class PerceptionFrame:
    """One step's input to a pose source.

    ``observation`` is the env's observation (images under ``<camera>_rgb`` and the like,
    proprioception); ``cameras`` the public calibration of each camera, keyed by name;
    ``object_name`` the object's identity when the user passes it (else ``None``: the source
    must recognise it); ``truth`` the true pose (``{"position", "quaternion"}``), given to
    privileged sources only; ``step`` the number of env steps since reset; ``backgrounds``
    each camera's reference frame of the empty workspace (``info["camera_background"]`` from
    the reset, when the env captures one: ``{"rgb", "joint_pos", "gripper_opening"}``).
    """

    observation: dict[str, np.ndarray] = field(default_factory=dict)
    cameras: dict[str, CameraModel] = field(default_factory=dict)
    object_name: str | None = None
    truth: dict[str, Any] | None = None
    step: int = 0
    backgrounds: dict[str, dict[str, Any]] = field(default_factory=dict)


@dataclass
class WorldPose:
    """An object pose estimate in the world frame (metres; quaternion w, x, y, z).

    ``valid=False`` means no pose could be estimated (``reason`` says why). ``object_name`` is
    the class the source used (recognised or given); ``timings_ms`` holds per-stage times.
    """

    position: np.ndarray
    quaternion: np.ndarray
    valid: bool
    confidence: float = 1.0
    object_name: str | None = None
    n_keypoints: int = 0
    n_inliers: int = 0
    timings_ms: dict[str, float] = field(default_factory=dict)
    reason: str = ""
    camera: str | None = None
    #: what the source saw beyond the pose, for the record (e.g. ``"blobs"``: per-object
    #: recognitions on a cluttered table); never enters the observation
    details: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def invalid(cls, reason: str, **kwargs: Any) -> WorldPose:
        return cls(np.full(3, np.nan), np.full(4, np.nan), False, 0.0, reason=reason, **kwargs)

    @property
    def rotation(self) -> np.ndarray:
        return quat_to_mat(self.quaternion)


@runtime_checkable
class PoseSource(Protocol):
    """``reset`` at the start of each episode, then ``estimate`` whenever the wrapper asks."""

    #: observation entries the source reads (e.g. ``"top_rgb"``; empty for the oracle family)
    required_keys: tuple[str, ...]
    #: whether it reads the ground truth (oracle family): reported with every result
    privileged: bool

    def reset(self, frame: PerceptionFrame, rng: np.random.Generator) -> None: ...

    def estimate(self, frame: PerceptionFrame) -> WorldPose: ...
