"""What a learned policy is told about the object besides its pose: its class, or its grasp frame.

A one-hot over the training catalogue (``"class"``) lets a network learn each object's grasp by
heart, and says nothing about an object it never trained on: there the one-hot is all zeros and
the policy grasps as it would some average object. The grasp frame (``"grasp_frame"``) is what
the scripted controller derives from the object's mesh and its estimated pose, for any object:
where the fingers close (the grasp point, at the height the controller grasps), along which
horizontal line, how wide the object is there and how tall it stands. Two objects with the same
grasp frame are grasped the same way, whatever their names; a new object's frame comes from its
mesh the same way (issue 49, item 5).

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
#: values of the grasp frame: grasp point relative to the TCP (3), its height above the table,
#: sin/cos of twice the closing line's heading relative to the base, the wrist and its mirror
#: (6), the object's width at the grasp and its height above the table
N_GRASP_FRAME = 12


def n_object_features(kind: str, n_classes: int) -> int:
    """How many values ``kind`` gives for a policy trained on ``n_classes`` classes."""
    check_object_features(kind)
    return n_classes if kind == "class" else N_GRASP_FRAME


def check_object_features(kind: object) -> None:
    if kind not in OBJECT_FEATURES:
        raise ValueError(f"object_features must be one of {OBJECT_FEATURES}, got {kind!r}")


def object_name(obs: dict[str, np.ndarray], class_names: Sequence[str]) -> str | None:
    """The object the observation's ``object_class`` one-hot names (``None`` without one)."""
    onehot = obs.get("object_class")
    if onehot is None or not len(class_names) or float(np.max(onehot)) < 0.5:
        return None
    return class_names[int(np.argmax(onehot))]


def grasp_frame_features(obs: dict[str, np.ndarray], name: str | None) -> np.ndarray:
    """The grasp frame of object ``name`` at the observation's pose (module docstring); zeros
    before the episode's first estimate (a placeholder pose) or without an identity."""
    out = np.zeros(N_GRASP_FRAME, np.float32)
    quat = np.asarray(obs["object_quat"], float)
    if name is None or not np.any(quat):  # the wrapper's placeholder before any estimate
        return out
    model = get_object(name).model
    pos = np.asarray(obs["object_pos"], float)
    R = observed_rotation(obs)
    gx, gy, _ = pos + R @ np.r_[model.grasp_point, 0.0]
    top = pos[2] + float((model.vertices @ R[2]).max())
    z = max(pos[2], top - 0.05, TABLE_HEIGHT + 0.012)  # as the controller grasps (_plan)
    closing = horizontal_closing_yaw(R, model.grasp_yaw)
    q = np.asarray(obs["joint_pos"], float)
    ee = np.asarray(obs["ee_pos"], float)
    angles = 2.0 * np.array([closing - q[0], closing - q[0] - q[4], closing - q[0] + q[4]])
    out[:3] = np.array([gx, gy, z]) - ee
    out[3] = z - TABLE_HEIGHT
    out[4:7], out[7:10] = np.sin(angles), np.cos(angles)
    out[10] = float(model.grasp_width)
    out[11] = top - TABLE_HEIGHT
    return out
