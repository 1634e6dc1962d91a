"""A thin facade over one compiled MuJoCo scene: state, stepping, rendering, cameras."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import mujoco  # the package's __init__ has already chosen the GL backend
import numpy as np

from pose.camera import CameraModel
from scorbot_gym.names import MOVING_CAMERAS
from scorbot_gym.objects import ObjectSpec, get_object
from scorbot_gym.sim import cameras as cam_utils
from scorbot_gym.sim._memory import release_freed_memory
from scorbot_gym.sim.arm import ARM_JOINTS, HOME_QPOS
from scorbot_gym.sim.rendering import SceneRenderer
from scorbot_gym.sim.scene import (
    DEFAULT_CAMERAS,
    HIDDEN_GROUP,
    MAX_RENDER_HEIGHT,
    MAX_RENDER_WIDTH,
    SUPPORT_NAME,
    TABLE_HEIGHT,
    VISIBLE_OBJECT_GROUP,
    WORKSPACE_X,
    WORKSPACE_Y,
    build_multi_scene,
    build_scene,
)

RenderKind = Literal["rgb", "depth", "segmentation"]
ARM_PREFIX = "scorbot/"


def check_render_size(width: int, height: int, what: str = "render size") -> None:
    """ValueError unless ``width`` x ``height`` is a positive size that fits the framebuffer."""
    for name, v, top in (("width", width, MAX_RENDER_WIDTH), ("height", height, MAX_RENDER_HEIGHT)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
            raise ValueError(f"{what} {name} must be an int in [1, {top}], got {v!r}")
        if v < 1:
            raise ValueError(f"{what} {name} must be in [1, {top}], got {v}")
        if v > top:
            raise ValueError(
                f"{what} {width}x{height} exceeds the framebuffer "
                f"(max {MAX_RENDER_WIDTH}x{MAX_RENDER_HEIGHT})"
            )


def _release_compiler_memory() -> None:
    """Drop what compiling a scene leaves behind: MuJoCo's process-wide asset cache keeps the
    decoded mesh and texture (~9 MB per object) to speed up a recompile of the same file, which
    an env never does (each scene is compiled once and kept; recompiling the same object in
    the same process then takes ~0.15 s instead of ~0.05 s), and glibc keeps the compiler's
    freed scratch memory (see ``benchmarks/env_memory.py``)."""
    mujoco.mj_clearCache(mujoco.mj_getCache())
    release_freed_memory()


def quat_from_yaw(yaw: float) -> np.ndarray:
    return np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])


def quat_to_mat(quat: np.ndarray) -> np.ndarray:
    """Rotation matrix (3x3) of a (w, x, y, z) quaternion."""
    R = np.empty(9)
    mujoco.mju_quat2Mat(R, np.asarray(quat, float))
    return R.reshape(3, 3)


def mat_to_quat(R: np.ndarray) -> np.ndarray:
    """Unit (w, x, y, z) quaternion with w >= 0 of a rotation matrix."""
    q = np.empty(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(R, float).ravel())
    return q if q[0] >= 0 else -q


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    out = np.empty(4)
    mujoco.mju_mulQuat(out, np.asarray(a, float), np.asarray(b, float))
    return out


def resting_pose(
    spec: ObjectSpec, xy: Sequence[float], yaw: float, resting_index: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Pose of object ``spec`` resting on the table on its face ``resting_index`` at ``xy`` with
    heading ``yaw`` (radians): its lowest point half a millimetre above the table top. The env
    places objects so, and the image-blind pose sources answer so without looking."""
    rests = spec.resting_quats
    if not 0 <= resting_index < len(rests):
        raise ValueError(f"resting_index must be in [0, {len(rests)}), got {resting_index}")
    quat = quat_mul(quat_from_yaw(yaw), np.asarray(rests[resting_index], float))
    lowest = (spec.mesh_vertices() @ quat_to_mat(quat).T)[:, 2].min()
    return np.array([xy[0], xy[1], TABLE_HEIGHT - lowest + 5e-4]), quat


@dataclass(frozen=True)
class SceneObject:
    """Where one free object of a compiled scene lives in ``qpos``/``qvel`` and its geoms;
    ``parkable``: in a multi-object scene, where it floats out of sight until placed."""

    spec: ObjectSpec
    body: int
    qpos: slice
    qvel: slice
    geoms: np.ndarray
    parkable: bool

    @classmethod
    def find(cls, m: mujoco.MjModel, spec: ObjectSpec, multi: bool) -> SceneObject:
        body = m.body(f"{spec.name}/object").id
        free = m.body_jntadr[m.body_rootid[body]]  # on the attachment frame
        return cls(
            spec,
            body,
            slice(m.jnt_qposadr[free], m.jnt_qposadr[free] + 7),
            slice(m.jnt_dofadr[free], m.jnt_dofadr[free] + 6),
            np.flatnonzero(m.geom_bodyid == body),
            multi,
        )


class Simulation:
    """One scene (arena, SCORBOT arm, one object) and its renderer.

    ``others`` adds more free objects (a scene for clutter, see
    :func:`~scorbot_gym.sim.scene.build_multi_scene`): all parked at reset; a task puts some on
    the table with :meth:`unpark` and picks the one the ``object_*`` members refer to with
    :meth:`select_object`. ``cluttered=True`` builds that scene (parking, the support stand) even
    for one object: a one-object catalogue with the target propped on the stand.

    ``shadows=True`` turns on the key light's shadow map (slower in software rendering).

    ``renderer`` lets several simulations share one :class:`SceneRenderer` (one GL context);
    without it the simulation makes its own. GL state is only created when an image is first
    asked for.
    """

    def __init__(
        self,
        object_name: str | ObjectSpec = "tomato_soup_can",
        cameras: Sequence[cam_utils.CameraSpec] = DEFAULT_CAMERAS,
        render_width: int = 640,
        render_height: int = 480,
        shadows: bool = False,
        renderer: SceneRenderer | None = None,
        others: Sequence[str | ObjectSpec] = (),
        cluttered: bool = False,
    ) -> None:
        spec = object_name if isinstance(object_name, ObjectSpec) else get_object(object_name)
        check_render_size(render_width, render_height)
        self.object_spec = spec
        self.camera_specs = {c.name: c for c in cameras}
        self.render_width, self.render_height = render_width, render_height
        self.shadows = shadows
        other_specs = [o if isinstance(o, ObjectSpec) else get_object(o) for o in others]
        multi = bool(other_specs) or cluttered
        if multi:  # several objects: parked until placed (see build_multi_scene)
            mjcf_model = build_multi_scene([spec, *other_specs], cameras)
        else:
            mjcf_model = build_scene(spec, cameras)
        self.model = mujoco.MjModel.from_xml_string(
            mjcf_model.to_xml_string(), mjcf_model.get_assets()
        )
        self.data = mujoco.MjData(self.model)
        del mjcf_model
        _release_compiler_memory()
        self._owns_renderer = renderer is None
        self.renderer = renderer or SceneRenderer(render_width, render_height, shadows)

        m = self.model
        self.objects = {s.name: SceneObject.find(m, s, multi=multi) for s in [spec, *other_specs]}
        self.select_object(spec.name)
        self.arm_qpos = np.array([m.joint(ARM_PREFIX + j).qposadr[0] for j in ARM_JOINTS])
        self.reset()

    def select_object(self, name: str) -> None:
        """Make ``name`` the object that ``object_pose``, ``set_object_pose``, ``resting_pose``,
        ``object_geoms`` and the segmentation render refer to (in a scene of several objects;
        a task's target, say)."""
        if name not in self.objects:
            raise ValueError(f"object {name!r} is not in this scene; it has {list(self.objects)}")
        o = self.objects[name]
        self.object_spec, self.object_body = o.spec, o.body
        self.object_qpos, self.object_qvel, self.object_geoms = o.qpos, o.qvel, o.geoms

    # --- state -----------------------------------------------------------------------------
    @property
    def camera_names(self) -> tuple[str, ...]:
        return tuple(self.camera_specs) + MOVING_CAMERAS

    @property
    def table_height(self) -> float:
        return TABLE_HEIGHT

    @property
    def workspace_xy_bounds(self) -> tuple[tuple[float, float], tuple[float, float]]:
        return WORKSPACE_X, WORKSPACE_Y

    @property
    def max_depth(self) -> float:
        """Depth reported where a ray hits nothing (the far clipping plane), metres."""
        return float(self.model.vis.map.zfar * self.model.stat.extent)

    @property
    def timestep(self) -> float:
        return float(self.model.opt.timestep)

    def reset(self) -> None:
        """Arm at home with servos holding it, object at its default place (in a scene of
        several objects: every object parked and hidden)."""
        mujoco.mj_resetData(self.model, self.data)
        for o in self.objects.values():
            if o.parkable:
                self.model.geom_group[o.geoms] = HIDDEN_GROUP
                self.model.body_gravcomp[o.body] = 1.0
        self.data.qpos[self.arm_qpos] = HOME_QPOS
        self.data.ctrl[: len(ARM_JOINTS)] = HOME_QPOS
        self.forward()

    def forward(self) -> None:
        mujoco.mj_forward(self.model, self.data)

    def step(self, n: int = 1) -> None:
        mujoco.mj_step(self.model, self.data, nstep=n)

    def set_object_pose(self, pos: np.ndarray, quat: np.ndarray) -> None:
        q = np.asarray(quat, dtype=float)
        self.data.qpos[self.object_qpos] = np.r_[np.asarray(pos, float), q / np.linalg.norm(q)]
        self.data.qvel[self.object_qvel] = 0.0

    def object_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """Position and unit quaternion (w, x, y, z) of the object frame in the world."""
        q = self.data.qpos[self.object_qpos]
        return q[:3].copy(), q[3:].copy()

    def resting_pose(
        self, xy: Sequence[float], yaw: float, resting_index: int = 0, name: str | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Pose of the object (or object ``name``) resting on the table at ``xy`` with heading
        ``yaw`` (radians)."""
        spec = self.object_spec if name is None else self.objects[name].spec
        return resting_pose(spec, xy, yaw, resting_index)

    # --- several objects ---------------------------------------------------------------------
    def pose_of(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """Position and unit quaternion of object ``name`` (any object of the scene)."""
        q = self.data.qpos[self.objects[name].qpos]
        return q[:3].copy(), q[3:].copy()

    def set_pose_of(self, name: str, pos: np.ndarray, quat: np.ndarray) -> None:
        o = self.objects[name]
        q = np.asarray(quat, dtype=float)
        self.data.qpos[o.qpos] = np.r_[np.asarray(pos, float), q / np.linalg.norm(q)]
        self.data.qvel[o.qvel] = 0.0

    def unpark(self, name: str) -> None:
        """Give object ``name`` its weight back and show it (a multi-object scene); the caller
        then puts it somewhere with :meth:`set_pose_of`."""
        o = self.objects[name]
        if not o.parkable:
            raise ValueError(f"object {name!r} is not parked (a single-object scene)")
        self.model.body_gravcomp[o.body] = 0.0
        self.model.geom_group[o.geoms] = VISIBLE_OBJECT_GROUP

    def on_table(self) -> tuple[str, ...]:
        """The objects not parked (every object of a single-object scene)."""
        return tuple(n for n, o in self.objects.items() if not self.model.body_gravcomp[o.body])

    def set_objects_visible(self, names: Sequence[str], visible: bool) -> None:
        """Show or hide objects in every image without moving them (e.g. for a background
        frame of the empty workspace)."""
        group = VISIBLE_OBJECT_GROUP if visible else HIDDEN_GROUP
        for n in names:
            self.model.geom_group[self.objects[n].geoms] = group

    def set_support(
        self, pos: np.ndarray, quat: np.ndarray, half_size: tuple[float, float], lip: float
    ) -> None:
        """Put the support stand (multi-object scenes) at ``pos``/``quat`` (its plate's centre
        and orientation; the plate's top face is its local +z face), with a plate of half
        length x width ``half_size`` and a lip ``lip`` m high along the plate's +x edge."""
        m, d = self.model, self.data
        plate, lip_geom = m.geom("support_plate"), m.geom("support_lip")
        thick = float(plate.size[2])
        plate.size[:2] = half_size
        lip_geom.size[:] = (0.004, half_size[1], lip / 2 + thick)
        lip_geom.pos[:] = (half_size[0] + 0.004, 0.0, lip / 2)
        mocap = m.body_mocapid[m.body(SUPPORT_NAME).id]
        d.mocap_pos[mocap] = pos
        d.mocap_quat[mocap] = quat
        for g in (plate, lip_geom):  # the collision bounds (sphere and box) follow the sizes
            m.geom_rbound[g.id] = float(np.linalg.norm(g.size))
            m.geom_aabb[g.id] = np.r_[0.0, 0.0, 0.0, g.size]

    def park_support(self) -> None:
        m = self.model
        mocap = m.body_mocapid[m.body(SUPPORT_NAME).id]
        self.data.mocap_pos[mocap] = m.body_pos[m.body(SUPPORT_NAME).id]

    # --- cameras and rendering -------------------------------------------------------------
    def camera_id(self, camera: str) -> int:
        full = ARM_PREFIX + camera if camera in MOVING_CAMERAS else camera
        cam_id = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_CAMERA, full)
        if cam_id < 0:
            raise ValueError(
                f"unknown camera {camera!r}; valid cameras: {', '.join(self.camera_names)}"
            )
        return cam_id

    def camera_model(
        self, camera: str, width: int | None = None, height: int | None = None
    ) -> CameraModel:
        """Intrinsics and extrinsics (OpenCV convention) that match what ``render`` shows."""
        cam_id = self.camera_id(camera)
        w, h = width or self.render_width, height or self.render_height
        K = cam_utils.intrinsics(float(self.model.cam_fovy[cam_id]), w, h)
        T = cam_utils.world_from_camera(self.data.cam_xpos[cam_id], self.data.cam_xmat[cam_id])
        return CameraModel(K=K, world_from_camera=T, width=w, height=h, name=camera)

    def render(
        self,
        camera: str,
        kind: RenderKind = "rgb",
        width: int | None = None,
        height: int | None = None,
    ) -> np.ndarray:
        """RGB ``uint8 (H, W, 3)``, depth ``float32 (H, W)`` in metres along the optical axis,
        or the object's segmentation mask ``bool (H, W)``."""
        if kind not in ("rgb", "depth", "segmentation"):
            raise ValueError(f"render kind must be 'rgb', 'depth' or 'segmentation', got {kind!r}")
        cam_id = self.camera_id(camera)
        w, h = width or self.render_width, height or self.render_height
        check_render_size(w, h)
        out = self.renderer.render(self.model, self.data, cam_id, kind, w, h)
        if kind == "segmentation":
            is_geom = out[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM)
            return is_geom & np.isin(out[..., 0], self.object_geoms)
        return out

    def close(self) -> None:
        """Free this scene's GL state (all of the renderer's if this simulation made it)."""
        if self._owns_renderer:
            self.renderer.close()
        else:
            self.renderer.release(self.model)
