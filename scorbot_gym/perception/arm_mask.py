"""Where the robot's own arm is in a camera image, from the robot model alone.

A background-subtraction segmenter sees the moving arm as foreground. The arm is known: its
kinematic model (the same MJCF the simulator mounts, compiled on its own as in
:class:`scorbot_gym.robot.kinematics.ArmKinematics`), the measured joint angles and gripper
opening from the observation, and the camera's public calibration are enough to render its
silhouette. No simulator state is read, so a policy-side process (or a real robot cell with a
calibrated camera) can do the same.
"""

from __future__ import annotations

import mujoco
import numpy as np

from pose.camera import CameraModel
from scorbot_gym import _gl
from scorbot_gym.robot.kinematics import ARM_PREFIX
from scorbot_gym.sim.arm import ARM_JOINTS, build_arm
from scorbot_gym.sim.simulation import mat_to_quat

mjcf = _gl.import_mjcf()  # dm_control with its own renderer off (see _gl)


class ArmMaskRenderer:
    """Render the arm's silhouette at given joint angles for a calibrated camera.

    One offscreen renderer per image size, created on first use and reused; the model holds
    one free-standing camera whose pose and field of view are set from each
    :class:`~pose.camera.CameraModel` (principal point at the image centre, as MuJoCo renders).
    """

    def __init__(self, base_pos=None) -> None:
        if base_pos is None:
            from scorbot_gym.sim.scene import TABLE_HEIGHT

            base_pos = (0.0, 0.0, TABLE_HEIGHT)
        root = mjcf.RootElement(model="scorbot_silhouette")
        root.compiler.angle = "radian"
        root.visual.get_children("global").offwidth = 1280
        root.visual.get_children("global").offheight = 960
        root.worldbody.add("camera", name="view", pos=[0, 0, 1])
        site = root.worldbody.add("site", name="robot_base", pos=list(base_pos))
        site.attach(build_arm())
        self.model = mujoco.MjModel.from_xml_string(root.to_xml_string(), root.get_assets())
        self.data = mujoco.MjData(self.model)
        m = self.model
        self._qpos = np.array([m.joint(ARM_PREFIX + j).qposadr[0] for j in ARM_JOINTS])
        self._fingers = np.array(
            [m.joint(ARM_PREFIX + f"finger_{s}").qposadr[0] for s in ("left", "right")]
        )
        self._cam = m.camera("view").id
        self._renderers: dict[tuple[int, int], mujoco.Renderer] = {}

    def _set_camera(self, camera: CameraModel) -> None:
        T = np.asarray(camera.world_from_camera, float)
        R_mj = T[:3, :3] @ np.diag([1.0, -1.0, -1.0])  # OpenCV axes -> MuJoCo's (-z forward)
        self.model.cam_pos[self._cam] = T[:3, 3]
        self.model.cam_quat[self._cam] = mat_to_quat(R_mj)
        fy = float(camera.K[1, 1])
        self.model.cam_fovy[self._cam] = np.rad2deg(2.0 * np.arctan(0.5 * camera.height / fy))

    def render(
        self, camera: CameraModel, joint_pos: np.ndarray, gripper_opening: float = 0.0
    ) -> np.ndarray:
        """``(H, W)`` bool: pixels where ``camera`` sees the arm at ``joint_pos``."""
        r = self._posed(camera, joint_pos, gripper_opening)
        seg = r.render()
        return (seg[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM)) & (seg[..., 0] >= 0)

    def render_with_depth(
        self, camera: CameraModel, joint_pos: np.ndarray, gripper_opening: float = 0.0
    ) -> tuple[np.ndarray, np.ndarray]:
        """The arm's mask (as :meth:`render`) and its depth ``(H, W)`` in metres along the
        optical axis (meaningful inside the mask): where a camera calibration from the
        silhouette needs the arm's 3-D points."""
        r = self._posed(camera, joint_pos, gripper_opening)
        seg = r.render()
        mask = (seg[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM)) & (seg[..., 0] >= 0)
        r.disable_segmentation_rendering()
        r.enable_depth_rendering()
        try:
            depth = r.render().copy()
        finally:
            r.disable_depth_rendering()
            r.enable_segmentation_rendering()
        return mask, depth

    def _posed(
        self, camera: CameraModel, joint_pos: np.ndarray, gripper_opening: float
    ) -> mujoco.Renderer:
        """The renderer for ``camera``'s image size, its scene set to the arm at ``joint_pos``."""
        q = np.asarray(joint_pos, float).ravel()
        if q.shape != (len(ARM_JOINTS),) or not np.all(np.isfinite(q)):
            raise ValueError(f"joint_pos must be {len(ARM_JOINTS)} finite angles, got {q}")
        self._set_camera(camera)
        d = self.data
        d.qpos[self._qpos] = q
        d.qpos[self._fingers] = float(np.ravel(gripper_opening)[0]) / 2.0
        mujoco.mj_kinematics(self.model, d)
        mujoco.mj_camlight(self.model, d)
        key = (int(camera.width), int(camera.height))
        if key not in self._renderers:
            _gl.prepare_first_context()
            r = mujoco.Renderer(self.model, key[1], key[0])
            _gl.track_gl_owner(self)  # released before a fork (see scorbot_gym._gl)
            r.enable_segmentation_rendering()
            self._renderers[key] = r
        r = self._renderers[key]
        r.update_scene(d, camera=self._cam)
        return r

    def close(self) -> None:
        """Free the GL contexts (the next :meth:`render` makes them again)."""
        for r in self._renderers.values():
            r.close()
        self._renderers.clear()

    def release_gl(self) -> None:
        """Free the GL contexts before this process forks (:mod:`scorbot_gym._gl`)."""
        self.close()

    def __getstate__(self) -> dict:
        """GL contexts cannot be pickled or copied: they are dropped and made again lazily."""
        return {k: v for k, v in self.__dict__.items() if k != "_renderers"}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._renderers = {}

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:
            pass
