"""Orthogonal, seeded perturbation axes for rendered views and for the env (off by default).

A :class:`Perturbation` says how strongly each axis is perturbed; every rendered frame draws its
own perturbation from ``seed`` and the frame's index, with one random stream *per axis*, so
turning one axis on or up never changes what another axis draws (the axes are orthogonal: an
ablation over one axis compares like with like on the others).

Axes:

- ``lighting``: every light's diffuse intensity scaled by ``U[1 - a, 1 + a]``, its direction
  turned by up to ``30 a`` degrees, the headlight's ambient term scaled likewise.
- ``surfaces``: table and floor recoloured (material tint ``U[1 - a, 1]`` per channel) and their
  texture repeat scaled by ``2^U[-a, a]``: a different-looking table and background. The texture
  images themselves are not replaced (MuJoCo uploads them once per renderer).
- ``camera_pos_m`` / ``camera_rot_deg``: extrinsics error of the fixed (eye-to-hand) cameras, a
  miscalibration: the image comes from a camera moved by ``N(0, pos)`` metres per axis and turned
  by ``N(0, rot)`` degrees about a random axis, while the estimator is given the *nominal*
  camera (:meth:`ScenePerturber.nominal_camera_model`). The eye-in-hand camera is not moved.
- ``blur_sigma`` (pixels, Gaussian) then ``noise_sigma`` (intensity levels of 255, Gaussian):
  sensor blur and noise, applied to the finished RGB image.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass, fields

import cv2
import mujoco
import numpy as np

from pose.camera import CameraModel

_AXES = ("lighting", "surfaces", "camera", "image")
_SURFACE_MATERIALS = ("table_mat", "floor_mat")


@dataclass(frozen=True)
class Perturbation:
    """Strength of each perturbation axis (all 0 = off) and the seed they are drawn from."""

    lighting: float = 0.0
    surfaces: float = 0.0
    camera_pos_m: float = 0.0
    camera_rot_deg: float = 0.0
    blur_sigma: float = 0.0
    noise_sigma: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name != "seed" and not (np.isfinite(v) and v >= 0):
                raise ValueError(f"perturbation {f.name} must be a finite value >= 0, got {v}")
        for name in ("lighting", "surfaces"):
            if getattr(self, name) > 1:
                raise ValueError(
                    f"perturbation {name} must be within [0, 1], got {getattr(self, name)}"
                )

    @property
    def active(self) -> bool:
        return any(getattr(self, f.name) for f in fields(self) if f.name != "seed")

    @property
    def scene_active(self) -> bool:
        return bool(self.lighting or self.surfaces or self.camera_pos_m or self.camera_rot_deg)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def parse(cls, text: str | None) -> Perturbation:
        """From ``"lighting=0.3,noise_sigma=4,seed=2"`` (the CLI form); empty means off."""
        if not text:
            return cls()
        names = {f.name for f in fields(cls)}
        kw: dict = {}
        for part in text.split(","):
            key, sep, value = part.partition("=")
            key = key.strip()
            if not sep or key not in names:
                raise ValueError(
                    f"bad perturbation {part!r}; use KEY=VALUE pairs with KEY in {sorted(names)}"
                )
            try:
                kw[key] = int(value) if key == "seed" else float(value)
            except ValueError as exc:
                raise ValueError(f"perturbation {key} needs a number, got {value!r}") from exc
        return cls(**kw)

    def rng(self, index: int | Sequence[int], axis: str) -> np.random.Generator:
        """The random stream of one axis for frame ``index`` (an int or a tuple of ints, e.g.
        ``(episode, step, camera)``), independent of the other axes' streams."""
        idx = [int(index)] if np.isscalar(index) else [int(i) for i in index]
        return np.random.default_rng([self.seed, *idx, _AXES.index(axis)])

    def apply_image(self, image: np.ndarray, index: int | Sequence[int]) -> np.ndarray:
        """Blur then noise on a ``uint8`` image (a no-op when both are 0)."""
        if not (self.blur_sigma or self.noise_sigma):
            return image
        out = image
        if self.blur_sigma:
            out = cv2.GaussianBlur(out, (0, 0), self.blur_sigma)
        if self.noise_sigma:
            noise = self.rng(index, "image").normal(0.0, self.noise_sigma, out.shape)
            out = np.clip(out.astype(np.float32) + noise, 0, 255).astype(np.uint8)
        return out


def _turn(rng: np.random.Generator, angle_deg: float) -> np.ndarray:
    """Quaternion of a turn by ``angle_deg`` about a uniformly random axis."""
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    half = np.radians(angle_deg) / 2
    return np.r_[np.cos(half), np.sin(half) * axis]


class ScenePerturber:
    """Applies a :class:`Perturbation`'s scene axes to one simulation's compiled model.

    The nominal model values are recorded at construction; :meth:`apply` first restores them,
    then draws frame ``index``'s perturbation, so frames never accumulate changes. Call the
    simulation's ``forward()`` afterwards (light and camera poses are computed there).
    """

    def __init__(self, sim) -> None:
        self.sim = sim
        m = sim.model
        self._fixed = [sim.camera_id(c) for c in sim.camera_specs]
        self._mats = [
            i for i in (mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_MATERIAL, n)
                        for n in _SURFACE_MATERIALS) if i >= 0
        ]  # fmt: skip
        self._nominal = {
            "light_diffuse": m.light_diffuse.copy(),
            "light_dir": m.light_dir.copy(),
            "ambient": m.vis.headlight.ambient.copy(),
            "mat_rgba": m.mat_rgba.copy(),
            "mat_texrepeat": m.mat_texrepeat.copy(),
            "cam_pos": m.cam_pos.copy(),
            "cam_quat": m.cam_quat.copy(),
        }

    def restore(self) -> None:
        m, n = self.sim.model, self._nominal
        m.light_diffuse[:], m.light_dir[:] = n["light_diffuse"], n["light_dir"]
        m.vis.headlight.ambient[:] = n["ambient"]
        m.mat_rgba[:], m.mat_texrepeat[:] = n["mat_rgba"], n["mat_texrepeat"]
        m.cam_pos[:], m.cam_quat[:] = n["cam_pos"], n["cam_quat"]

    def apply(self, p: Perturbation, index: int | Sequence[int]) -> None:
        self.restore()
        m = self.sim.model
        if p.lighting:
            rng = p.rng(index, "lighting")
            a = p.lighting
            m.light_diffuse[:] *= rng.uniform(1 - a, 1 + a, (m.nlight, 1))
            for i in range(m.nlight):
                d = np.empty(3)
                mujoco.mju_rotVecQuat(d, m.light_dir[i].copy(), _turn(rng, rng.uniform(0, 30 * a)))
                m.light_dir[i] = d
            m.vis.headlight.ambient[:] = self._nominal["ambient"] * rng.uniform(1 - a, 1 + a)
        if p.surfaces:
            rng = p.rng(index, "surfaces")
            a = p.surfaces
            for i in self._mats:
                m.mat_rgba[i, :3] = self._nominal["mat_rgba"][i, :3] * rng.uniform(1 - a, 1.0, 3)
                m.mat_texrepeat[i] = self._nominal["mat_texrepeat"][i] * 2.0 ** rng.uniform(-a, a)
        if p.camera_pos_m or p.camera_rot_deg:
            rng = p.rng(index, "camera")
            for c in self._fixed:
                m.cam_pos[c] += rng.normal(0.0, p.camera_pos_m, 3)
                q = np.empty(4)
                mujoco.mju_mulQuat(
                    q, _turn(rng, rng.normal(0.0, p.camera_rot_deg)), m.cam_quat[c].copy()
                )
                m.cam_quat[c] = q

    def nominal_camera_model(self, camera: str, width: int, height: int) -> CameraModel:
        """The calibration the estimator is given: the camera as built, not as perturbed."""
        from scorbot_gym.sim import cameras as cam_utils

        cid = self.sim.camera_id(camera)
        if cid not in self._fixed:
            return self.sim.camera_model(camera, width, height)
        R = np.empty(9)
        mujoco.mju_quat2Mat(R, self._nominal["cam_quat"][cid])
        K = cam_utils.intrinsics(float(self.sim.model.cam_fovy[cid]), width, height)
        T = cam_utils.world_from_camera(self._nominal["cam_pos"][cid], R)
        return CameraModel(K=K, world_from_camera=T, width=width, height=height, name=camera)
