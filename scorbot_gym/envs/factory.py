"""Build a grasping env with perception in the loop, in one call (CLI, benchmarks, RL).

``make_env(pose="manifold", pose_kwargs={"models": path})`` creates the pose source first, asks
it which cameras, image size and image types it reads (``env_requirements``), makes the env
render exactly those, and wraps it with :class:`PoseEstimateObservation`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import gymnasium as gym

from scorbot_gym.envs.worker import built_or_failed
from scorbot_gym.perception.base import PoseSource
from scorbot_gym.perception.registry import make_pose_source
from scorbot_gym.wrappers.pose_observation import PoseEstimateObservation


def make_env(
    env_id: str = "ScorbotGrasp-v0",
    *,
    pose: str | PoseSource = "oracle",
    pose_kwargs: dict[str, Any] | None = None,
    estimate_every: int = 1,
    rotation: str = "quat",
    include_class: bool = True,
    classes: list[str] | None = None,
    identity: str = "given",
    keep_images: bool = False,
    timings_in_info: bool = False,
    pose_cameras: Sequence[str] | None = None,
    neighbours: bool | None = None,
    **env_kwargs: Any,
) -> gym.Env:
    """``gym.make(env_id, **env_kwargs)`` wrapped with a pose source's estimates.

    Camera settings the pose source needs are merged into ``env_kwargs``; a conflicting
    setting given by the caller is an error, not silently overridden. ``identity="recognize"``
    withholds the object's identity from the source (it recognises it); ``pose_cameras`` are
    the cameras a named source may use (``cameras=`` of its factory, e.g. ``["top", "side"]``
    for recognition fused over both); ``timings_in_info`` puts the wrapper's wall-clock
    ``perception_timings`` in ``info["perception"]`` too. ``neighbours`` adds the other
    objects on the table to the observation (``neighbour_points``, ``neighbour_valid``; see
    :class:`PoseEstimateObservation`); ``None``: where the env has distractors and the source
    reports them. Examples: ``pose_kwargs={"models": path, "segmenter": "background",
    "recognizer": "appearance"}``.

    In a Gymnasium vector-env worker, an error here (a bad model path, say) reaches the main
    process as itself (:mod:`scorbot_gym.envs.worker`). The env's spec records the pose source
    and its arguments, a model set by its file, so ``gym.make(env.spec)`` rebuilds the env.
    """
    settings = dict(
        pose=pose,
        pose_kwargs=pose_kwargs,
        estimate_every=estimate_every,
        rotation=rotation,
        include_class=include_class,
        classes=classes,
        identity=identity,
        keep_images=keep_images,
        timings_in_info=timings_in_info,
        pose_cameras=pose_cameras,
        neighbours=neighbours,
    )
    return built_or_failed(lambda: _make_env(env_id, **settings, **env_kwargs))


def _make_env(
    env_id: str,
    *,
    pose: str | PoseSource,
    pose_kwargs: dict[str, Any] | None,
    estimate_every: int,
    rotation: str,
    include_class: bool,
    classes: list[str] | None,
    identity: str,
    keep_images: bool,
    timings_in_info: bool,
    pose_cameras: Sequence[str] | None,
    neighbours: bool | None,
    **env_kwargs: Any,
) -> gym.Env:
    pose_kwargs = dict(pose_kwargs or {})
    if pose_cameras is not None:
        if not isinstance(pose, str):
            raise ValueError("pose_cameras is only accepted with a pose source name")
        if isinstance(pose_cameras, str) or not pose_cameras:
            raise ValueError(
                f"pose_cameras must be a non-empty list of camera names, got {pose_cameras!r}"
            )
        pose_kwargs["cameras"] = list(pose_cameras)
    source = make_pose_source(pose, **pose_kwargs)
    needs = dict(getattr(source, "env_requirements", {}))
    if "cameras" in needs:
        cams = list(env_kwargs.get("cameras", ()))
        needs["cameras"] = cams + [c for c in needs["cameras"] if c not in cams]
    if "image_types" in needs:
        types = list(env_kwargs.get("image_types", ("rgb",)))
        needs["image_types"] = types + [t for t in needs["image_types"] if t not in types]
    for key in ("image_width", "image_height"):
        if key in needs and key in env_kwargs and env_kwargs[key] != needs[key]:
            raise ValueError(
                f"{key}={env_kwargs[key]} conflicts with the pose source, which reads "
                f"{needs[key]}-pixel images"
            )
    env = gym.make(env_id, **{**env_kwargs, **needs})
    try:
        if neighbours is None:
            neighbours = bool(env.get_wrapper_attr("distractors")) and callable(
                getattr(source, "neighbours", None)
            )
        return PoseEstimateObservation(
            env,
            source,
            estimate_every=estimate_every,
            rotation=rotation,
            include_class=include_class,
            classes=classes,
            identity=identity,
            keep_images=keep_images,
            timings_in_info=timings_in_info,
            neighbours=neighbours,
        )
    except BaseException:
        env.close()  # its renderer's GL context goes with it
        raise
