"""Episode videos, optionally with the estimated pose drawn on every frame.

The overlay shows what the policy believes: the object frame's axes (x red, y green, z blue) at
the pose in the observation, projected with the video camera's public calibration; a grey
frame when the held estimate is stale (``pose_age > 0``) and none before the first valid one.
It also marks the target (a yellow ring with its name, where ``info`` says it truly is): on a
cluttered table a viewer sees at once whether the estimate sits on the target or on a neighbour.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

import cv2
import numpy as np

from pose.camera import CameraModel
from pose.fileio import atomic_write_bytes
from scorbot_gym.evaluation.episodes import EpisodeResult, run_episode
from scorbot_gym.sim.simulation import quat_to_mat

VIDEO_SUFFIXES = (".mp4", ".gif")
_AXIS_COLOURS = ((230, 40, 40), (40, 200, 40), (40, 90, 240))
_TARGET_COLOUR = (250, 220, 30)


def draw_pose(
    frame: np.ndarray,
    camera: CameraModel,
    position: np.ndarray,
    rotation: np.ndarray,
    length: float = 0.05,
    stale: bool = False,
) -> np.ndarray:
    """``frame`` with the axes of the pose (world frame) drawn on a copy."""
    out = np.ascontiguousarray(frame.copy())
    pts = np.vstack([position, position + length * np.asarray(rotation).T])
    cam_pts = (camera.camera_from_world @ np.c_[pts, np.ones(4)].T).T[:, :3]
    if np.any(cam_pts[:, 2] <= 1e-3):
        return out  # behind the camera
    uv = camera.project(pts)
    o = tuple(int(round(v)) for v in uv[0])
    for k in range(3):
        colour = (150, 150, 150) if stale else _AXIS_COLOURS[k]
        p = tuple(int(round(v)) for v in uv[k + 1])
        cv2.line(out, o, p, colour, 2, cv2.LINE_AA)
    return out


def draw_target(
    frame: np.ndarray, camera: CameraModel, position: np.ndarray, name: str, radius_m: float
) -> np.ndarray:
    """``frame`` with a ring of ``radius_m`` around ``position`` (world) and ``name`` beside it,
    drawn on a copy (nothing where the point is behind the camera)."""
    out = np.ascontiguousarray(frame.copy())
    p = np.asarray(position, float)
    if (camera.camera_from_world @ np.r_[p, 1.0])[2] <= 1e-3:
        return out
    uv = camera.project(np.vstack([p, p + [0.0, 0.0, radius_m]]))
    centre = tuple(int(round(v)) for v in uv[0])
    r = max(6, int(round(np.linalg.norm(uv[1] - uv[0]))) + 3)
    cv2.circle(out, centre, r, _TARGET_COLOUR, 1, cv2.LINE_AA)
    scale = max(0.3, frame.shape[0] / 800)
    org = (centre[0] + r + 2, centre[1] - r)
    cv2.putText(out, name, org, cv2.FONT_HERSHEY_SIMPLEX, scale, _TARGET_COLOUR, 1, cv2.LINE_AA)
    return out


def _radius(name: str) -> float:
    """The object's bounding radius (m), the size of its ring."""
    from scorbot_gym.objects import get_object

    return float(np.linalg.norm(get_object(name).mesh_vertices(), axis=1).max())


def draw_overlay(
    frame: np.ndarray, camera: CameraModel, obs: dict[str, np.ndarray], info: dict
) -> np.ndarray:
    """One video frame's overlay: the target marked (from ``info``) and the estimated pose's
    axes (from the observation: what the policy acts on), on a copy."""
    name = info.get("object_name")
    if name is not None and "object_pose" in info:
        position = info["object_pose"]["position"]
        frame = draw_target(frame, camera, position, name, _radius(name))
    pose = pose_from_observation(obs)
    if pose is not None:
        stale = "pose_age" in obs and obs["pose_age"][0] > 0
        frame = draw_pose(frame, camera, *pose, stale=stale)
    return frame


def pose_from_observation(obs: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray] | None:
    """Position and rotation matrix the observation carries, or None before the first estimate."""
    if "object_pos" not in obs or ("pose_valid" in obs and obs["pose_age"][0] >= 1000):
        return None
    if "object_quat" in obs:
        R = quat_to_mat(np.asarray(obs["object_quat"], float))
    elif "object_yaw" in obs:
        s, c = np.asarray(obs["object_yaw"], float)
        R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    else:
        return None
    return np.asarray(obs["object_pos"], float), R


def record_episode(
    env: Any,
    policy: Any,
    seed: int,
    path: str | os.PathLike,
    overlay: bool = False,
    options: dict | None = None,
) -> tuple[EpisodeResult, int]:
    """Run one episode of ``env`` (made with ``render_mode="rgb_array"``) and write its frames
    to ``path`` (MP4 or GIF, atomically); returns the result and the number of frames."""
    results, n = record_episodes(env, policy, [seed], path, overlay, options)
    return results[0], n


def record_episodes(
    env: Any,
    policy: Any,
    seeds: Sequence[int],
    path: str | os.PathLike,
    overlay: bool = False,
    options: dict | None = None,
) -> tuple[list[EpisodeResult], int]:
    """Run one episode per seed of ``env`` (made with ``render_mode="rgb_array"``) and write
    all their frames, one episode after the other, to ``path`` (MP4 or GIF, atomically);
    returns the results and the number of frames."""
    import imageio.v3 as iio

    from scorbot_gym.outputs import check_output_file

    check_output_file(path, "video", VIDEO_SUFFIXES)  # before the episodes
    suffix = os.fspath(path).lower()[-4:]
    base = env.unwrapped
    frames: list[np.ndarray] = []
    camera: CameraModel | None = None

    def on_step(obs: dict, info: dict) -> None:
        nonlocal camera
        frame = env.render()
        if overlay:
            h, w = frame.shape[:2]
            if camera is None:  # fixed camera: its calibration is read once
                camera = base.camera_model(base.render_camera, w, h)
            frame = draw_overlay(frame, camera, obs, info)
        frames.append(frame)

    results = [run_episode(env, policy, s, options=options, on_step=on_step) for s in seeds]
    fps = env.metadata["render_fps"]
    if suffix == ".gif":
        data = iio.imwrite("<bytes>", frames[::2], extension=".gif", duration=2000 / fps, loop=0)
    else:
        data = iio.imwrite("<bytes>", frames, extension=".mp4", fps=fps, macro_block_size=8)
    atomic_write_bytes(path, data)
    return results, len(frames)
