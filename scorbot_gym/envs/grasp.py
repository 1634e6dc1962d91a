"""``ScorbotGrasp-v0``: pick up one object from the table with a SCORBOT-ER Vplus."""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium import spaces
from gymnasium.error import ResetNeeded

from pose.camera import CameraModel
from scorbot_gym.data.perturbations import Perturbation, ScenePerturber
from scorbot_gym.envs import arguments as args
from scorbot_gym.objects import derive_missing_models, get_object
from scorbot_gym.robot import JOINT_HIGH, JOINT_LOW, Robot, tool_pitch
from scorbot_gym.sim.arm import GRIPPER_MAX_OPENING
from scorbot_gym.sim.rendering import SceneRenderer
from scorbot_gym.sim.simulation import MOVING_CAMERAS, Simulation, check_render_size
from scorbot_gym.tasks import GraspTask
from scorbot_gym.tasks.clutter import ClutterTask
from scorbot_gym.tasks.disturbance import Disturbance, make_disturbance
from scorbot_gym.tasks.grasp import REWARD_GAMMA, reward_gamma_for

ACTION_TYPES = ("joint", "cartesian")
#: how Cartesian actions become joint targets (``cartesian_ik``)
CARTESIAN_IKS = ("closed_form", "dls")
# "privileged_segmentation" is the simulator's own object mask: for oracle and ablation
# experiments only (a real camera gives no such image), hence the name.
IMAGE_TYPES = ("rgb", "depth", "privileged_segmentation")
_INSTABILITY_WARNINGS = np.array(
    [
        mujoco.mjtWarning.mjWARN_BADQPOS,
        mujoco.mjtWarning.mjWARN_BADQVEL,
        mujoco.mjtWarning.mjWARN_BADQACC,
        mujoco.mjtWarning.mjWARN_BADCTRL,
    ],
    dtype=np.intp,
)


class ScorbotGraspEnv(gym.Env):
    """Grasp and lift one catalogue object, watched by fixed eye-to-hand cameras.

    Actions (all in [-1, 1]; values outside are clipped to the space, NaN/inf raise):

    - ``action_type="joint"``: deltas for the 5 arm joints, scaled by ``max_joint_step`` rad and
      added to the measured joint angles, then the gripper command (-1 closed ... +1 open).
    - ``action_type="cartesian"``: TCP delta x, y, z (scaled by ``max_cartesian_step`` m), tool
      pitch and wrist roll deltas (scaled by ``max_angle_step`` rad), then the gripper command;
      joint targets come from the arm's closed-form IK on the current branch, with damped least
      squares where that has no answer (out of reach, at a limit, a branch change):
      ``cartesian_ik="closed_form"``, the default. ``cartesian_ik="dls"`` solves every step by
      damped least squares (15 iterations), as every result before 2026-11-28 did; the two give
      the same joint targets within the least squares' tolerance (0.1 mm, 1 mrad).

    Reward (``reward_type="dense"``, designed for ``gamma = 0.99``): shaping for reaching the
    grasp point (<= 1), grasping (1) and lifting (<= 2), at most 4 per step, plus a one-off
    success bonus of ``1.5 * 4 / (1 - 0.99) = 600`` on the step that succeeds (which
    terminates the episode). The bonus is larger than the discounted value of collecting the
    largest shaping reward forever (``4 / (1 - 0.99) = 400``, what holding the object just
    below the lift height is worth when the time limit is bootstrapped), so finishing is worth
    more than any way of not finishing; see :func:`scorbot_gym.tasks.grasp.grasp_reward`.
    ``info["reward_reach"]``, ``["reward_grasp"]``, ``["reward_lift"]``, ``["reward_success"]``
    are the terms (Gymnasium MuJoCo v5 style; 0 at reset). Every shipped policy and result
    was trained with it. ``reward_type="normalized_dense"`` (for learning from scratch, also
    designed for ``gamma = 0.99``): every step's reward in [0, 1]; reach ``1 - tanh(3 d)``,
    grasp, lift and hold progress, their mean times 0.005 on a step that does not succeed,
    nothing on a step with an arm collision, and at least 0.995 on the success step, so that
    never finishing is worth at most 0.5 and a success within 68 steps more; terms in
    ``info["reward_reach" | "reward_grasp" | "reward_lift" | "reward_hold" |
    "reward_collision" | "reward_success"]``, see
    :func:`scorbot_gym.tasks.grasp.normalized_grasp_reward`.
    ``reward_type="normalized_pregrasp"``: the same with a fifth stage after reach, the hand in
    a pre-grasp pose (closing line turned to the object's, the tool pointing down, the hand
    open until 2 cm from the grasp point; ``info["reward_pregrasp"]``;
    :func:`scorbot_gym.tasks.grasp.pregrasp_progress`).
    ``reward_type="sparse"``: 1 on success, else 0.
    ``reward_gamma`` (normalised rewards only; default 0.99): the discount they are built for,
    ``w = (1 - reward_gamma) / 2`` (0.1 at 0.8: shaping 20 times larger beside a success);
    see :func:`scorbot_gym.tasks.grasp.normalized_shaping_max`.

    ``info["failure_cause"]`` is ``None`` once the episode is a success; before that, it is the
    reason the episode counts as failed if it ends at this step: ``missed``, ``dropped``,
    ``collision`` (the arm hit the table, knocked the object, or hit itself), ``timeout``
    (nothing went wrong, there was just no success yet) or ``unstable`` (the physics blew up or
    a servo command was not finite; the episode is then truncated).

    Every keyword is checked here (:mod:`scorbot_gym.envs.arguments`); ``step`` before ``reset``
    raises Gymnasium's ``ResetNeeded``.

    ``disturbance`` moves the object while the arm approaches (``"push"``: one seeded push and
    turn before the grasp; ``"slide"``: a slow steady slide until the robot touches it; or a
    :class:`~scorbot_gym.tasks.disturbance.Disturbance` object); ``info["disturbance"]`` says
    what happened. Off by default.

    Observations are proprioception only, unless ``observe_object_pose=True`` (oracle) or
    ``cameras`` are given (then ``<camera>_rgb`` / ``<camera>_depth`` images are added). The
    object's true pose is always in ``info["object_pose"]``; the cameras' calibration is in
    ``info["camera_params"]`` after ``reset``, after every step for a camera the arm carries
    (``eye_in_hand``), and from :meth:`camera_params` at any time.

    ``capture_background=True`` adds ``info["camera_background"]`` at reset: per camera, the
    empty workspace (object not yet in the scene, arm where it is at reset) as ``{"rgb",
    "joint_pos", "gripper_opening"}`` - the reference frame a lab captures before placing the
    object, for background-subtraction segmenters.

    ``perturbation`` (a :class:`~scorbot_gym.data.perturbations.Perturbation`, off by default)
    redraws lighting, table/floor look and fixed-camera extrinsics error at every reset and adds
    blur/noise to every RGB frame, all from the reset seed; ``camera_model`` / ``camera_params``
    keep reporting the nominal calibration.

    ``distractors`` puts other objects on the table beside the target: ``K`` drawn per episode
    from ``objects`` (the target excluded), or a list of names on the table in every episode
    (then not targets). ``tilt_deg`` props the target on a stand so that it rests that many
    degrees out of its resting pose. The target is drawn from ``objects`` at reset, or named by
    ``options={"target": name}`` (one of them; option keys other than ``target``,
    ``object_name`` and ``resting_index`` are refused); with either option on, the observation
    gains ``target_class`` (one-hot over :attr:`target_classes`, the task command), ``info`` gains
    ``target_name``, ``objects`` (every object's ground truth: role, pose, tilt, knocked over),
    ``distractors_knocked_over`` and ``wrong_object``, and ``failure_cause`` can be
    ``wrong_object`` (a distractor lifted between the fingers). Objects are placed seeded and
    without interpenetration (:class:`~scorbot_gym.tasks.clutter.ClutterTask`). With both off
    (the default) the env is the single-object one, observation and physics unchanged.
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
        disturbance: str | Disturbance | None = None,
        capture_background: bool = False,
        perturbation: Perturbation | None = None,
        distractors: int | Sequence[str] = 0,
        tilt_deg: float = 0.0,
        cartesian_ik: str = "closed_form",
        reward_gamma: float = REWARD_GAMMA,
    ) -> None:
        if action_type not in ACTION_TYPES:
            raise ValueError(f"action_type must be one of {ACTION_TYPES}, got {action_type!r}")
        if cartesian_ik not in CARTESIAN_IKS:
            raise ValueError(f"cartesian_ik must be one of {CARTESIAN_IKS}, got {cartesian_ik!r}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode must be one of {self.metadata['render_modes']} or None, "
                f"got {render_mode!r}"
            )
        image_types = args.name_list("image_types", image_types, "rgb")
        bad = [t for t in image_types if t not in IMAGE_TYPES]
        if bad or not image_types:
            raise ValueError(f"image_types must be a non-empty subset of {IMAGE_TYPES}, got {bad}")
        self.object_names = args.object_names(object_name, objects)
        explicit = object_name is not None or objects is not None
        self.distractors = args.distractors(distractors, self.object_names, explicit)
        if isinstance(self.distractors, tuple):  # named distractors are never targets
            self.object_names = tuple(n for n in self.object_names if n not in self.distractors)
        self.tilt_deg = args.tilt_deg(tilt_deg)
        #: the classes a target can be, in the order of the ``target_class`` one-hot
        self.target_classes = self.object_names
        self._cluttered = bool(self.distractors) or self.tilt_deg > 0
        self._clutter: ClutterTask | None = None
        self._target_onehot = np.zeros(len(self.target_classes))
        self.cameras = args.name_list("cameras", cameras, "top")
        check_render_size(image_width, image_height, "image size")
        check_render_size(render_width, render_height, "render size")
        self.frame_skip = args.int_in_range("frame_skip", frame_skip, 1, args.MAX_FRAME_SKIP)
        self.max_joint_step = args.step_scale("max_joint_step", max_joint_step)
        self.max_cartesian_step = args.step_scale("max_cartesian_step", max_cartesian_step)
        self.max_angle_step = args.step_scale("max_angle_step", max_angle_step)
        self.observe_object_pose = args.flag("observe_object_pose", observe_object_pose)
        self.shadows = args.flag("shadows", shadows)
        self.action_type, self.reward_type = action_type, reward_type
        self.reward_gamma = reward_gamma_for(reward_type, reward_gamma)
        self.cartesian_ik = cartesian_ik
        self.image_types = image_types
        self.image_width, self.image_height = image_width, image_height
        self.render_mode, self.render_camera = render_mode, render_camera
        self.render_width, self.render_height = render_width, render_height
        self.disturbance = disturbance
        self._disturbance = make_disturbance(disturbance)
        self._disturbance_info: dict[str, Any] | None = None
        self._elapsed = 0
        self.capture_background = args.flag("capture_background", capture_background)
        if perturbation is not None and not isinstance(perturbation, Perturbation):
            raise ValueError(f"perturbation must be a Perturbation or None, got {perturbation!r}")
        self.perturbation = perturbation if perturbation is not None else Perturbation()
        self._perturbers: dict[str, ScenePerturber] = {}
        self._episode, self._frame = 0, 0

        # One GL context for all scenes, its buffer as large as the largest image asked for.
        sizes = [(image_width, image_height)] if self.cameras else []
        sizes += [(render_width, render_height)] if render_mode else []
        self._renderer = SceneRenderer(
            max((w for w, _ in sizes), default=image_width),
            max((h for _, h in sizes), default=image_height),
            self.shadows,
        )
        self._needs_reset = True
        self._sims: dict[str, tuple[Simulation, Robot, GraspTask]] = {}
        scene_names = self.object_names + (
            self.distractors if isinstance(self.distractors, tuple) else ()
        )
        derive_missing_models([get_object(n) for n in scene_names])  # first run only
        self._activate(self.object_names[0])
        for cam in (*self.cameras, render_camera):
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
        if self._cluttered:
            n = len(self.target_classes)
            obs_spaces["target_class"] = spaces.Box(0.0, 1.0, shape=(n,), dtype=np.float64)
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
        # Looked up once: the readings are clipped to them every step.
        self._obs_bounds = {key: (space.low, space.high) for key, space in obs_spaces.items()}

    # --- plumbing ------------------------------------------------------------------------
    def _activate(self, name: str) -> None:
        """Switch to the scene holding ``name``: compiled on first use and kept (~8 MB each),
        as recompiling takes longer than a reset should; all scenes share one renderer and
        one arm kinematics model. With distractors or tilt, one scene holds every object."""
        if self._cluttered:
            self._activate_cluttered(name)
            return
        if name not in self._sims:
            sim = Simulation(
                name,
                render_width=self.image_width,
                render_height=self.image_height,
                shadows=self.shadows,
                renderer=self._renderer,
            )
            first = next(iter(self._sims.values()), None)
            robot = Robot(sim, first[1].kinematics if first else None)
            self._sims[name] = (
                sim,
                robot,
                GraspTask(sim, robot, self.reward_type, reward_gamma=self.reward_gamma),
            )
            self._perturbers[name] = ScenePerturber(sim)
        self.sim, self.robot, self.task = self._sims[name]
        self._perturber = self._perturbers[name]

    def _activate_cluttered(self, target: str) -> None:
        if not self._sims:
            names = self.object_names
            others = names[1:] + (self.distractors if isinstance(self.distractors, tuple) else ())
            sim = Simulation(
                names[0],
                render_width=self.image_width,
                render_height=self.image_height,
                shadows=self.shadows,
                renderer=self._renderer,
                others=others,
                cluttered=True,
            )
            robot = Robot(sim)
            task = GraspTask(sim, robot, self.reward_type, reward_gamma=self.reward_gamma)
            self._sims["clutter"] = (sim, robot, task)
            self._perturbers["clutter"] = ScenePerturber(sim)
            self._clutter = ClutterTask(sim, robot, task, tilt_deg=self.tilt_deg)
        self.sim, self.robot, self.task = self._sims["clutter"]
        self._perturber = self._perturbers["clutter"]
        if target not in self.target_classes:
            raise ValueError(
                f"target {target!r} is not one of this env's targets {list(self.target_classes)}"
            )
        self.sim.select_object(target)

    def _draw_distractors(self, target: str) -> tuple[str, ...]:
        if isinstance(self.distractors, tuple):
            return self.distractors
        pool = [n for n in self.object_names if n != target]
        picked = self.np_random.choice(len(pool), size=self.distractors, replace=False)
        return tuple(pool[int(i)] for i in picked)

    @property
    def dt(self) -> float:
        return self.sim.timestep * self.frame_skip

    # --- gym API -------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        options = args.reset_options(options)
        name = args.reset_target(options, self.target_classes)
        if name is None:
            name = self.object_names[int(self.np_random.integers(len(self.object_names)))]
        spec = get_object(name)
        name = spec.name
        resting_index = args.resting_index(options.get("resting_index", 0), spec)  # before use
        self._activate(name)
        self.sim.reset()
        if self._clutter is not None:
            self.sim.unpark(name)
        self.task.place_object(self.np_random, resting_index)
        self.robot.set_gripper_target(GRIPPER_MAX_OPENING)
        self.sim.data.qpos[self.robot.finger_qpos] = GRIPPER_MAX_OPENING / 2
        if self._clutter is not None:  # distractors, and the target on its stand, then settle
            self._clutter.place(self.np_random, name, self._draw_distractors(name), resting_index)
            self._target_onehot = (np.array(self.target_classes) == name).astype(np.float64)
        if self.perturbation.active:  # drawn only when on: unperturbed episodes keep their seeds
            self._episode, self._frame = int(self.np_random.integers(2**31)), 0
            self._perturber.apply(self.perturbation, self._episode)
        self.sim.forward()
        self._elapsed = 0
        if self._disturbance is not None:  # drawn after placement: placements stay the same
            self._disturbance.reset(self.np_random)
            self._disturbance_info = None
        self._needs_reset = False
        info = self._info(None, None, calibration=True)
        info.update({f"reward_{k}": 0.0 for k in self.task.reward_terms})
        if self.capture_background and self.cameras:
            info["camera_background"] = self._background_frames()
        return self._observation(), info

    def step(self, action):
        if self._needs_reset:
            raise ResetNeeded("Cannot call env.step() before calling env.reset()")
        a = np.asarray(action, dtype=np.float64)
        if a.shape != self.action_space.shape:
            raise ValueError(f"action must have shape {self.action_space.shape}, got {a.shape}")
        if not np.isfinite(a).all():
            raise ValueError(f"action contains NaN or inf: {a.tolist()}")
        a = np.minimum(np.maximum(a, -1.0), 1.0)  # np.clip's result without its ~5 us overhead
        q = self.robot.joint_pos
        if self.action_type == "joint":
            target = q + a[:5] * self.max_joint_step
        else:
            target = self._cartesian_target(q, a)
        self.robot.set_joint_targets(target)
        self.robot.set_gripper_target((a[5] + 1.0) / 2.0 * GRIPPER_MAX_OPENING)

        unstable = self._simulate()
        facts = self.task.update(self.dt) if not unstable else {"fell": False, "grasped": False}
        if self._clutter is not None and not unstable:
            self._clutter.update()
        self._elapsed += 1
        if self._disturbance is not None and not unstable:
            touched = facts["touched"] or facts["lift"] > 0.005  # contacts found by the task
            self._disturbance_info = self._disturbance.apply(
                self.sim, self._elapsed, self.dt, touched
            )
        success = self.task.state.success and not unstable
        reward, terms = (0.0, {}) if unstable else self.task.reward(facts)
        terminated = success or bool(facts["fell"])
        truncated = unstable  # the time limit is Gymnasium's TimeLimit wrapper (see make)
        # Defined on every step, so the final step carries it whoever ends the episode.
        cause = None if success else self.task.failure_cause(facts, unstable)
        if cause not in (None, "unstable") and self._clutter and self._clutter.wrong_object:
            cause = "wrong_object"
        if unstable:
            self.sim.reset()  # leave a finite state behind for observations and rendering
        info = self._info(facts, cause)
        info.update({f"reward_{k}": terms.get(k, 0.0) for k in self.task.reward_terms})
        return self._observation(), reward, terminated, truncated, info

    def _cartesian_target(self, q: np.ndarray, a: np.ndarray) -> np.ndarray:
        pos = self.robot.tcp_pos + a[:3] * self.max_cartesian_step
        pitch = tool_pitch(q) + a[3] * self.max_angle_step
        kin = self.robot.kinematics
        target = kin.ik_closed_form(pos, pitch, q) if self.cartesian_ik == "closed_form" else None
        if target is None:
            target, _ = kin.ik(pos, pitch, q, iterations=15)
        target[4] = q[4] + a[4] * self.max_angle_step
        return target

    def _simulate(self) -> bool:
        """Run the physics substeps; True if the simulation went unstable."""
        d = self.sim.data
        self.sim.step(self.frame_skip)
        # MuJoCo resets the state itself on bad qpos/qvel/qacc and only leaves a warning count.
        warned = (d.warning.number[_INSTABILITY_WARNINGS] > 0).any()
        return bool(warned or not np.isfinite(d.qpos).all() or not np.isfinite(d.qvel).all())

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
        if self._cluttered:
            obs["target_class"] = self._target_onehot.copy()
        # MuJoCo's joint limits and contacts are soft: pushed hard (the hand folded onto the
        # column) a joint passes its stop by up to ~1 mrad and the fingers by ~1 mm. Readings
        # are clipped to the space, as the real controller's encoders stop at the limits.
        for key, value in obs.items():
            low, high = self._obs_bounds[key]
            np.minimum(np.maximum(value, low, out=value), high, out=value)
        self._frame += 1
        for i, cam in enumerate(self.cameras):  # rendered once per control step, when asked for
            if "rgb" in self.image_types:
                img = self.sim.render(cam, "rgb")
                idx = (self._episode, self._frame, i)
                obs[f"{cam}_rgb"] = self.perturbation.apply_image(img, idx)
            if "depth" in self.image_types:
                obs[f"{cam}_depth"] = self.sim.render(cam, "depth")[..., None]
            if "privileged_segmentation" in self.image_types:
                seg = self.sim.render(cam, "segmentation")
                obs[f"{cam}_privileged_segmentation"] = seg[..., None].astype(np.uint8)
        return obs

    def _background_frames(self) -> dict[str, dict[str, Any]]:
        """Each camera's view with the object taken out of the scene (then put back), taken by
        the same camera as the observations: under a blur/noise perturbation it is blurred
        too and has noise of its own (frame 0 of the episode's stream)."""
        pos, quat = self.sim.object_pose()
        on_table = self.sim.on_table() if self._clutter is not None else ()
        if on_table:  # hidden where they are (the scene keeps no free space to move them to)
            self.sim.set_objects_visible(on_table, False)
        else:
            self.sim.set_object_pose(pos + np.array([50.0, 50.0, -50.0]), quat)
        self.sim.forward()
        try:
            arm = {"joint_pos": self.robot.joint_pos}
            arm["gripper_opening"] = np.array([self.robot.gripper_opening])
            frames = {
                cam: {
                    "rgb": self.perturbation.apply_image(
                        self.sim.render(cam, "rgb"), (self._episode, 0, i)
                    ),
                    **arm,
                }
                for i, cam in enumerate(self.cameras)
            }
        finally:
            if on_table:
                self.sim.set_objects_visible(on_table, True)
            else:
                self.sim.set_object_pose(pos, quat)
            self.sim.forward()
        return frames

    def camera_model(
        self, camera: str, width: int | None = None, height: int | None = None
    ) -> CameraModel:
        """Intrinsics and extrinsics (OpenCV convention) of ``camera`` at the observation's image
        size (or ``width`` x ``height``, e.g. the ``render()`` size): the public calibration that
        wrappers, policies and video overlays may use. Under a camera ``perturbation`` this
        stays the nominal calibration (the images come from the perturbed camera), as with a
        miscalibrated real camera."""
        w, h = width or self.image_width, height or self.image_height
        if self.perturbation.active:
            return self._perturber.nominal_camera_model(camera, w, h)
        return self.sim.camera_model(camera, w, h)

    def object_visibility(self, camera: str) -> float:
        """Ground truth for scoring (never for a policy): the share of the target object that
        ``camera`` sees unhidden by the arm or another object, from rays to points of the object
        (:mod:`scorbot_gym.sim.visibility`). 1.0 is a clear view."""
        from scorbot_gym.sim.visibility import object_visibility

        sim = self.sim
        return object_visibility(sim.model, sim.data, sim.camera_id(camera), sim.object_geoms)

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
            # ground truth, for scoring: the TCP's distance to the grasp point, m (where an
            # episode that failed ended; the learning curves' stall diagnostic)
            "grasp_distance": float(
                facts["reach"] if facts and "reach" in facts else self._grasp_distance()
            ),
        }
        if self._clutter is not None:
            info["target_name"] = self.sim.object_spec.name
            info.update(self._clutter.info())
        if self._disturbance_info is not None:
            info["disturbance"] = self._disturbance_info
        # Calibration travels with the images (as ManiSkill's sensor_param): at reset for every
        # camera, then at every step for the cameras the arm carries only (vector envs would
        # pickle and merge the fixed cameras' constant arrays every step for nothing;
        # camera_params() gives them at any time).
        cams = [c for c in self.cameras if calibration or c in MOVING_CAMERAS]
        if cams:
            info["camera_params"] = {cam: self.camera_params(cam) for cam in cams}
        return info

    def _grasp_distance(self) -> float:
        return float(np.linalg.norm(self.robot.tcp_pos - self.task.grasp_point_world()))

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
        self._renderer.close()
