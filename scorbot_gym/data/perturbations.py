"""Orthogonal, seeded perturbation axes for rendered views and for the env (off by default).

A :class:`Perturbation` says how strongly each axis is perturbed; every rendered frame draws its
own perturbation from ``seed`` and the frame's index, with one random stream *per axis*, so
turning one axis on or up never changes what another axis draws (the axes are orthogonal: an
ablation over one axis compares like with like on the others).

Axes:

- ``lighting``: every light's diffuse intensity scaled by ``U[1 - a, 1 + a]``, its direction
  turned by up to ``30 a`` degrees, the headlight's ambient term scaled likewise.
- ``surfaces``: a different-looking table and background. The table's and the floor's texture
  images are blended, with weight ``a``, toward a random crop of a real photograph
  (:data:`SURFACE_PHOTOGRAPHS`, shipped with scikit-image, so nothing is downloaded), then
  recoloured (material tint ``U[1 - a, 1]`` per channel) and their texture repeat scaled by
  ``2^U[-a, a]``. A photograph puts real clutter under and behind the object: edges and corners
  on which SIFT fires, which a procedural texture does not have.
- ``camera_pos_m`` / ``camera_rot_deg``: extrinsics error of the fixed (eye-to-hand) cameras, a
  miscalibration: the image comes from a camera moved by ``N(0, pos)`` metres per axis and turned
  by ``N(0, rot)`` degrees about a random axis, while the estimator is given the *nominal*
  camera (:meth:`ScenePerturber.nominal_camera_model`). The eye-in-hand camera is not moved.
- ``blur_sigma`` (pixels, Gaussian) then ``noise_sigma`` (intensity levels of 255, Gaussian):
  sensor blur and noise, applied to the finished RGB image.
"""

from __future__ import annotations

import functools
import hashlib
from collections.abc import Sequence
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import cv2
import mujoco
import numpy as np

from pose.camera import CameraModel

_AXES = ("lighting", "surfaces", "camera", "image")
_SURFACE_MATERIALS = ("table_mat", "floor_mat")
#: the ``skimage.data`` photographs a ``surfaces`` perturbation draws from: surfaces (brick,
#: grass, gravel) and cluttered scenes (the rest)
SURFACE_PHOTOGRAPHS = ("brick", "grass", "gravel", "coffee", "chelsea", "astronaut", "rocket")


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

    @classmethod
    def parse_list(cls, text: str | None) -> list[tuple[str, Perturbation]]:
        """From ``"none;lighting=0.5;noise_sigma=8"`` (the benchmarks' ``--perturbations``):
        ``(label, perturbation)`` pairs, ``"none"`` the unperturbed one; empty means none."""
        labels = [t.strip() for t in (text or "").split(";") if t.strip()]
        return [(t, cls.parse(None if t == "none" else t)) for t in labels]

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


@functools.cache
def code_fingerprint() -> str:
    """Hash of this module's source. What a perturbed frame looks like is decided here, so the
    cache keys of perturbed views and of the trials on them include it (unperturbed ones do
    not: editing a perturbation leaves every clean cache entry valid)."""
    return hashlib.sha256(Path(__file__).read_bytes()).hexdigest()[:16]


@functools.cache
def surface_photographs() -> tuple[np.ndarray, ...]:
    """The :data:`SURFACE_PHOTOGRAPHS` as RGB ``uint8`` images (grey ones repeated per channel)."""
    import skimage.data

    out = []
    for name in SURFACE_PHOTOGRAPHS:
        img = np.asarray(getattr(skimage.data, name)(), np.uint8)
        out.append(np.repeat(img[..., None], 3, axis=2) if img.ndim == 2 else img[..., :3])
    return tuple(out)


def _photo_crop(rng: np.random.Generator, width: int, height: int) -> np.ndarray:
    """A random square crop (30-100 % of the shorter side) of a random photograph, resized to
    ``height x width``."""
    photos = surface_photographs()
    img = photos[rng.integers(len(photos))]
    side = int(min(img.shape[:2]) * rng.uniform(0.3, 1.0))
    y0 = rng.integers(img.shape[0] - side + 1)
    x0 = rng.integers(img.shape[1] - side + 1)
    crop = img[y0 : y0 + side, x0 : x0 + side]
    return cv2.resize(crop, (width, height), interpolation=cv2.INTER_AREA)


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
        rgb = int(mujoco.mjtTextureRole.mjTEXROLE_RGB)
        self._textures = sorted(
            {int(m.mat_texid[i, rgb]) for i in self._mats if m.mat_texid[i, rgb] >= 0}
            & {t for t in range(m.ntex)
               if m.tex_type[t] == mujoco.mjtTexture.mjTEXTURE_2D and m.tex_nchannel[t] == 3}
        )  # the 2-D RGB textures of the surface materials (the arena's are)  # fmt: skip
        self._nominal_tex = {t: self._tex_pixels(t).copy() for t in self._textures}
        self._tex_changed = False
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
        if self._tex_changed:
            for t, pixels in self._nominal_tex.items():
                self._tex_pixels(t)[:] = pixels
            self._textures_edited()
            self._tex_changed = False

    def _tex_pixels(self, t: int) -> np.ndarray:
        """Texture ``t``'s pixels, a writable ``(height, width, channels)`` view of ``tex_data``."""
        m = self.sim.model
        w, h, c = int(m.tex_width[t]), int(m.tex_height[t]), int(m.tex_nchannel[t])
        return m.tex_data[m.tex_adr[t] : m.tex_adr[t] + w * h * c].reshape(h, w, c)

    def _textures_edited(self) -> None:
        """The renderer uploaded the textures once; it must digest (and upload) them again."""
        self.sim.renderer.textures_changed(self.sim.model)

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
            for t, nominal in self._nominal_tex.items():
                h, w, _ = nominal.shape
                photo = _photo_crop(rng, w, h).astype(np.float32)
                blend = (1.0 - a) * nominal.astype(np.float32) + a * photo
                self._tex_pixels(t)[:] = np.clip(np.rint(blend), 0, 255).astype(np.uint8)
            if self._nominal_tex:
                self._tex_changed = True
                self._textures_edited()
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
