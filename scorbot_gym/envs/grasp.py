"""``ScorbotGrasp-v0``: pick up one object from the table with a SCORBOT-ER Vplus."""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium import spaces

from pose.camera import CameraModel
from scorbot_gym.objects import CATALOGUE, get_object
from scorbot_gym.robot import JOINT_HIGH, JOINT_LOW, Robot, tool_pitch
from scorbot_gym.sim.arm import GRIPPER_MAX_OPENING
from scorbot_gym.sim.simulation import Simulation
from scorbot_gym.tasks import GraspTask

ACTION_TYPES = ("joint", "cartesian")
# "privileged_segmentation" is the simulator's own object mask: for oracle and ablation
# experiments only (a real camera gives no such image), hence the name.
IMAGE_TYPES = ("rgb", "depth", "privileged_segmentation")
_INSTABILITY_WARNINGS = (
    mujoco.mjtWarning.mjWARN_BADQPOS,
    mujoco.mjtWarning.mjWARN_BADQVEL,
    mujoco.mjtWarning.mjWARN_BADQACC,
)


class ScorbotGraspEnv(gym.Env):
    """Grasp and lift one catalogue object, watched by fixed eye-to-hand cameras.

    Actions (all in [-1, 1]; values outside are clipped to the space, NaN/inf raise):

    - ``action_type="joint"``: deltas for the 5 arm joints, scaled by ``max_joint_step`` rad and
      added to the measured joint angles, then the gripper command (-1 closed ... +1 open).
    - ``action_type="cartesian"``: TCP delta x, y, z (scaled by ``max_cartesian_step`` m), tool
      pitch and wrist roll deltas (scaled by ``max_angle_step`` rad), then the gripper command;
      joint targets come from damped-least-squares IK.

    ``info["failure_cause"]`` is ``None`` once the episode is a success; before that, it is the
    reason the episode counts as failed if it ends at this step: ``missed``, ``dropped``,
    ``collision``, ``timeout`` (nothing went wrong, there was just no success yet) or
    ``unstable`` (the physics blew up; the episode is then truncated).

    Observations are proprioception only, unless ``observe_object_pose=True`` (oracle) or
    ``cameras`` are given (then ``<camera>_rgb`` / ``<camera>_depth`` images are added). The
    object's true pose is always in ``info["object_pose"]``; the cameras' calibration is in
    ``info["camera_params"]`` after ``reset`` (the cameras are fixed) and from
    :meth:`camera_params` at any time.
    """

    metadata = {"render_modes": ["rgb_array", "depth_array"], "render_fps": 25}

    def __init__(
        self,
        object_name: str | None = None,
        objects: Sequence[str] | None = None,
        action_type: str = "joint",
        reward_type: str = "dense",
        cameras: Sequence[str] = (),
        image_width: int = 640,
        image_height: int = 480,
        image_types: Sequence[str] = ("rgb",),
        observe_object_pose: bool = False,
        render_mode: str | None = None,
        render_camera: str = "overview",
        render_width: int = 640,
        render_height: int = 480,
        shadows: bool = False,
        frame_skip: int = 20,
        max_joint_step: float = 0.1,
        max_cartesian_step: float = 0.02,
        max_angle_step: float = 0.1,
    ) -> None:
        if action_type not in ACTION_TYPES:
            raise ValueError(f"action_type must be one of {ACTION_TYPES}, got {action_type!r}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode must be one of {self.metadata['render_modes']} or None, "
                f"got {render_mode!r}"
            )
        bad = [t for t in image_types if t not in IMAGE_TYPES]
        if bad or not image_types:
            raise ValueError(f"image_types must be a non-empty subset of {IMAGE_TYPES}, got {bad}")
        if frame_skip < 1:
            raise ValueError(f"frame_skip must be >= 1, got {frame_skip}")
        names = [object_name] if object_name is not None else list(objects or CATALOGUE)
        if not names:
            raise ValueError("objects must name at least one catalogue object")
        self.object_names = tuple(get_object(n).name for n in names)  # KeyError lists valid names
        self.action_type, self.reward_type = action_type, reward_type
        self.cameras, self.image_types = tuple(cameras), tuple(image_types)
        self.image_width, self.image_height = image_width, image_height
        self.observe_object_pose = observe_object_pose
        self.render_mode, self.render_camera = render_mode, render_camera
        self.render_width, self.render_height = render_width, render_height
        self.frame_skip = frame_skip
        self.shadows = shadows
        self.max_joint_step, self.max_cartesian_step = max_joint_step, max_cartesian_step
        self.max_angle_step = max_angle_step

        self._sims: dict[str, tuple[Simulation, Robot, GraspTask]] = {}
        self._activate(self.object_names[0])
        for cam in (*self.cameras, *([render_camera] if render_mode else [])):
            self.sim.camera_id(cam)  # ValueError listing the valid cameras

        self.action_space = spaces.Box(-1.0, 1.0, shape=(6,), dtype=np.float32)
        obs_spaces: dict[str, spaces.Space] = {
            "joint_pos": spaces.Box(JOINT_LOW, JOINT_HIGH, dtype=np.float64),
            "joint_vel": spaces.Box(-50.0, 50.0, shape=(5,), dtype=np.float64),
            "gripper_opening": spaces.Box(0.0, GRIPPER_MAX_OPENING + 1e-3, (1,), np.float64),
            "ee_pos": spaces.Box(-3.0, 3.0, shape=(3,), dtype=np.float64),
            "ee_quat": spaces.Box(-1.0, 1.0, shape=(4,), dtype=np.float64),
        }
        if observe_object_pose:
            obs_spaces["object_pos"] = spaces.Box(-3.0, 3.0, shape=(3,), dtype=np.float64)
            obs_spaces["object_quat"] = spaces.Box(-1.0, 1.0, shape=(4,), dtype=np.float64)
        shape = (image_height, image_width)
        for cam in self.cameras:
            if "rgb" in self.image_types:
                obs_spaces[f"{cam}_rgb"] = spaces.Box(0, 255, (*shape, 3), dtype=np.uint8)
            if "depth" in self.image_types:
                obs_spaces[f"{cam}_depth"] = spaces.Box(
                    0.0, 1.01 * self.sim.max_depth, (*shape, 1), np.float32
                )
            if "privileged_segmentation" in self.image_types:
                obs_spaces[f"{cam}_privileged_segmentation"] = spaces.Box(
                    0, 1, (*shape, 1), np.uint8
                )
        self.observation_space = spaces.Dict(obs_spaces)

    # --- plumbing ------------------------------------------------------------------------
    def _activate(self, name: str) -> None:
        """Switch to the scene holding ``name`` (scenes are compiled once and cached)."""
        if name not in self._sims:
            sim = Simulation(
                name,
                render_width=self.image_width,
                render_height=self.image_height,
                shadows=self.shadows,
            )
            robot = Robot(sim)
            self._sims[name] = (sim, robot, GraspTask(sim, robot, self.reward_type))
        self.sim, self.robot, self.task = self._sims[name]

    @property
    def dt(self) -> float:
        return self.sim.timestep * self.frame_skip

    # --- gym API -------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        options = options or {}
        name = options.get("object_name")
        if name is None:
            name = self.object_names[int(self.np_random.integers(len(self.object_names)))]
        self._activate(get_object(name).name)
        self.sim.reset()
        self.task.place_object(self.np_random, int(options.get("resting_index", 0)))
        self.robot.set_gripper_target(GRIPPER_MAX_OPENING)
        self.sim.data.qpos[self.robot.finger_qpos] = GRIPPER_MAX_OPENING / 2
        self.sim.forward()
        return self._observation(), self._info(None, None, calibration=True)

    def step(self, action):
        a = np.asarray(action, dtype=np.float64)
        if a.shape != self.action_space.shape:
            raise ValueError(f"action must have shape {self.action_space.shape}, got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"action contains NaN or inf: {a.tolist()}")
        a = np.clip(a, -1.0, 1.0)
        q = self.robot.joint_pos
        if self.action_type == "joint":
            target = q + a[:5] * self.max_joint_step
        else:
            target = self._cartesian_target(q, a)
        self.robot.set_joint_targets(target)
        self.robot.set_gripper_target((a[5] + 1.0) / 2.0 * GRIPPER_MAX_OPENING)

        unstable = self._simulate()
        facts = self.task.update(self.dt) if not unstable else {"fell": False, "grasped": False}
        success = self.task.state.success and not unstable
        reward = 0.0 if unstable else self.task.reward(facts)
        terminated = success or bool(facts["fell"])
        truncated = unstable  # the time limit is Gymnasium's TimeLimit wrapper (see make)
        # Defined on every step, so the final step carries it whoever ends the episode.
        cause = None if success else self.task.failure_cause(facts, unstable)
        if unstable:
            self.sim.reset()  # leave a finite state behind for observations and rendering
        return self._observation(), reward, terminated, truncated, self._info(facts, cause)

    def _cartesian_target(self, q: np.ndarray, a: np.ndarray) -> np.ndarray:
        pos = self.robot.tcp_pos + a[:3] * self.max_cartesian_step
        pitch = tool_pitch(q) + a[3] * self.max_angle_step
        target, _ = self.robot.kinematics.ik(pos, pitch, q, iterations=15)
        target[4] = q[4] + a[4] * self.max_angle_step
        return target

    def _simulate(self) -> bool:
        """Run the physics substeps; True if the simulation went unstable."""
        d = self.sim.data
        self.sim.step(self.frame_skip)
        # MuJoCo resets the state itself on bad qpos/qvel/qacc and only leaves a warning count.
        warned = any(d.warning[w].number > 0 for w in _INSTABILITY_WARNINGS)
        return bool(warned or not np.all(np.isfinite(d.qpos)) or not np.all(np.isfinite(d.qvel)))

    def _observation(self) -> dict[str, np.ndarray]:
        r = self.robot
        obs = {
            "joint_pos": r.joint_pos,
            "joint_vel": r.joint_vel,
            "gripper_opening": np.array([r.gripper_opening]),
            "ee_pos": r.tcp_pos,
            "ee_quat": r.tcp_quat,
        }
        if self.observe_object_pose:
            obs["object_pos"], obs["object_quat"] = self.sim.object_pose()
        for cam in self.cameras:  # rendered once per control step, only when asked for
            if "rgb" in self.image_types:
                obs[f"{cam}_rgb"] = self.sim.render(cam, "rgb")
            if "depth" in self.image_types:
                obs[f"{cam}_depth"] = self.sim.render(cam, "depth")[..., None]
            if "privileged_segmentation" in self.image_types:
                seg = self.sim.render(cam, "segmentation")
                obs[f"{cam}_privileged_segmentation"] = seg[..., None].astype(np.uint8)
        return obs

    def camera_model(self, camera: str) -> CameraModel:
        """Intrinsics and extrinsics (OpenCV convention) of ``camera`` at the observation's image
        size: the public calibration that wrappers and policies may use."""
        return self.sim.camera_model(camera, self.image_width, self.image_height)

    def camera_params(self, camera: str) -> dict[str, Any]:
        """:meth:`camera_model` as plain arrays (``K``, ``world_from_camera``, ``width``,
        ``height``), the form ``info["camera_params"]`` carries: it pickles across processes
        and compares by value; ``pose.camera.CameraModel(**params)`` turns it back."""
        cm = self.camera_model(camera)
        return {
            "K": cm.K,
            "world_from_camera": cm.world_from_camera,
            "width": cm.width,
            "height": cm.height,
            "name": camera,
        }

    def _info(
        self, facts: dict | None, cause: str | None, calibration: bool = False
    ) -> dict[str, Any]:
        pos, quat = self.sim.object_pose()
        st = self.task.state
        info = {
            "is_success": bool(st.success),
            "grasped": bool(facts["grasped"]) if facts else False,
            "object_pose": {"position": pos, "quaternion": quat},
            "object_name": self.sim.object_spec.name,
            "failure_cause": cause,
            "held_time": st.held_time,
        }
        # Calibration travels with the images (as ManiSkill's sensor_param), at reset only: the
        # cameras are fixed, and vector envs would pickle and merge the constant arrays every
        # step for nothing; camera_params() gives them at any time.
        if calibration and self.cameras:
            info["camera_params"] = {cam: self.camera_params(cam) for cam in self.cameras}
        return info

    def render(self):
        if self.render_mode is None:
            warnings.warn(
                "render() called without a render_mode; pass render_mode to make()", stacklevel=2
            )
            return None
        kind = "rgb" if self.render_mode == "rgb_array" else "depth"
        return self.sim.render(self.render_camera, kind, self.render_width, self.render_height)

    def close(self) -> None:
        for sim, _, _ in self._sims.values():
            sim.close()
