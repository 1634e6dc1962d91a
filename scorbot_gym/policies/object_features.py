"""What a learned policy is told about the object besides its pose: its class, or nothing but
its grasp frame.

A one-hot over the training catalogue (``"class"``) lets a network learn each object's grasp by
heart, and says nothing about an object it never trained on: there the one-hot is all zeros and
the policy grasps as it would some average object. With ``"grasp_frame"`` the network never sees
the object's own frame or its name: the estimated pose it reads is replaced by the object's
*grasp frame*, what the scripted controller derives from any object's mesh and pose (the grasp
point at the height the controller grasps, and the horizontal closing line as the heading), and
it gets no class input. Two objects with the same grasp frame are then the same input whatever
their names and shapes, and a new object's frame comes from its mesh the same way (issue 49,
item 5). Every pose feature (the object relative to the TCP, its heading relative to the base
and wrist, the window of fresh estimates) is then a grasp-frame feature.

The identity still picks the mesh: the observation's ``object_class`` one-hot, read against the
env's class names (every registered object, held-out ones included once installed).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from scorbot_gym.objects import get_object
from scorbot_gym.policies.grasp_clearance import horizontal_closing_yaw
from scorbot_gym.policies.scripted import observed_rotation
from scorbot_gym.sim.scene import TABLE_HEIGHT

#: what a policy can be told about the object (``policy.json``'s ``object_features``)
OBJECT_FEATURES = ("class", "grasp_frame")


def n_object_features(kind: str, n_classes: int) -> int:
    """How many values ``kind`` adds for a policy trained on ``n_classes`` classes: the one-hot,
    or none (the grasp frame replaces the pose, it adds nothing)."""
    check_object_features(kind)
    return n_classes if kind == "class" else 0


def check_object_features(kind: object) -> None:
    if kind not in OBJECT_FEATURES:
        raise ValueError(f"object_features must be one of {OBJECT_FEATURES}, got {kind!r}")


def object_name(obs: dict[str, np.ndarray], class_names: Sequence[str]) -> str | None:
    """The object the observation's ``object_class`` one-hot names (``None`` without one)."""
    onehot = obs.get("object_class")
    if onehot is None or not len(class_names) or float(np.max(onehot)) < 0.5:
        return None
    return class_names[int(np.argmax(onehot))]


def grasp_frame(obs: dict[str, np.ndarray], name: str) -> tuple[np.ndarray, float]:
    """Object ``name``'s grasp point (world) and closing-line heading at the observation's pose,
    as the scripted controller plans them (:meth:`ScriptedGraspPolicy._plan`)."""
    model = get_object(name).model
    pos = np.asarray(obs["object_pos"], float)
    R = observed_rotation(obs)
    gx, gy, _ = pos + R @ np.r_[model.grasp_point, 0.0]
    top = pos[2] + float((model.vertices @ R[2]).max())
    z = max(pos[2], top - 0.05, TABLE_HEIGHT + 0.012)
    return np.array([gx, gy, z]), horizontal_closing_yaw(R, model.grasp_yaw)


def grasp_frame_view(obs: dict[str, np.ndarray], name: str | None) -> dict[str, np.ndarray]:
    """``obs`` with its object pose replaced by the grasp frame of object ``name`` (an upright
    frame at the grasp point, turned to the closing line); unchanged before the episode's first
    estimate (the wrapper's zero placeholder) or without an identity."""
    quat = np.asarray(obs["object_quat"], float)
    if name is None or not np.any(quat):
        return obs
    point, closing = grasp_frame(obs, name)
    turn = np.array([np.cos(closing / 2), 0.0, 0.0, np.sin(closing / 2)])
    return {
        **obs,
        "object_pos": point.astype(np.float32),
        "object_quat": turn.astype(np.float32),
    }
