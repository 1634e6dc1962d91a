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

import gymnasium as gym
import numpy as np

from scorbot_gym.objects import get_object
from scorbot_gym.policies.grasp_clearance import horizontal_closing_yaw
from scorbot_gym.policies.scripted import observed_rotation, yaw_from_quat
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


#: what :func:`grasp_frame_observation` adds, and its size: the grasp point minus the TCP; sin
#: and cos of the doubled closing-line heading, absolute and relative to the base, and to the
#: wrist turned both ways (the imitation features' angles); 1 when the grasp frame was derived
GRASP_FRAME_ENTRIES = {"grasp_offset": 3, "grasp_heading": 8, "grasp_frame_valid": 1}


def grasp_frame_observation(
    obs: dict[str, np.ndarray], class_names: Sequence[str]
) -> dict[str, np.ndarray]:
    """``obs`` as an object-agnostic SB3 policy reads it: the pose replaced by the object's
    grasp frame (:func:`grasp_frame_view`), the class one-hot removed, and the frame relative
    to the hand added (:data:`GRASP_FRAME_ENTRIES`).

    Why the relative entries: ManiSkill's state observations give the TCP-to-object vector
    for the same reason; an MLP learns a difference of two inputs slowly, and from scratch
    every update it saves counts. ``grasp_frame_valid`` is 0 when there is no frame to give
    (no identity, or no estimate yet), so the fallback to the object's own pose is an input
    the policy sees, not a silent substitution.
    """
    name = object_name(obs, class_names)
    view = grasp_frame_view(obs, name)
    out = {k: v for k, v in view.items() if k != "object_class"}
    q = np.asarray(obs["joint_pos"], float)
    yaw = yaw_from_quat(np.asarray(view["object_quat"], float))
    angles = 2.0 * np.array([yaw, yaw - q[0], yaw - q[0] - q[4], yaw - q[0] + q[4]])
    offset = np.asarray(view["object_pos"], float) - np.asarray(obs["ee_pos"], float)
    out["grasp_offset"] = offset.astype(np.float32)
    out["grasp_heading"] = np.r_[np.sin(angles), np.cos(angles)].astype(np.float32)
    out["grasp_frame_valid"] = np.array([float(view is not obs)], np.float32)
    return out


def grasp_frame_space(space: gym.spaces.Dict) -> gym.spaces.Dict:
    """The observation space of :func:`grasp_frame_observation` for an env's ``space``."""
    entries = {k: s for k, s in space.spaces.items() if k != "object_class"}
    bounds = {"grasp_offset": 3.0, "grasp_heading": 1.0, "grasp_frame_valid": 1.0}
    for key, n in GRASP_FRAME_ENTRIES.items():
        low = 0.0 if key == "grasp_frame_valid" else -bounds[key]
        entries[key] = gym.spaces.Box(low, bounds[key], (n,), np.float32)
    return gym.spaces.Dict(entries)


class GraspFrameObservation(gym.ObservationWrapper):
    """An env's observations as :func:`grasp_frame_observation` gives them: what an
    object-agnostic SB3 policy trains on (``object_features: grasp_frame``). The env must give
    the ``object_class`` one-hot (``make_env``'s default) so that the frame's mesh is known."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        if "object_class" not in env.observation_space.spaces:
            raise ValueError(
                "GraspFrameObservation needs the object_class one-hot in the observation "
                "(make_env(..., include_class=True))"
            )
        self.class_names = tuple(env.get_wrapper_attr("class_names"))
        self.observation_space = grasp_frame_space(env.observation_space)

    def observation(self, observation: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        return grasp_frame_observation(observation, self.class_names)
