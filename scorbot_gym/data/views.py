"""Labelled views for the pose estimator, rendered by the simulator and cached on disk.

A view is the image, the object's visible mask, the camera model and the ground-truth pose of
one object resting on the table. Poses come from a grid (resting faces x headings x table
positions) for training and from seeded random samples for evaluation. Partial occlusion is
synthetic and exact: an occluder (a textured half-plane, pasted over the image) covers the
requested fraction of the object's mask, at a random, seeded angle.

Renders are cached under a content key (object, camera, image size, poses, occlusion, seed and
this module's format version), written atomically, so a second run costs a file read. An entry
that cannot be read is discarded with a warning and rendered again; temporary files left by a
killed write are removed on a later run.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from pose.camera import CameraModel
from pose.fileio import cached_npz
from pose.view import View
from scorbot_gym.data import cache_folder, default_cache_dir  # noqa: F401  (re-exported)
from scorbot_gym.data.perturbations import Perturbation, ScenePerturber
from scorbot_gym.data.perturbations import code_fingerprint as perturbation_code_fingerprint

CACHE_VERSION = 1
MAX_OCCLUSION = 0.95


@dataclass(frozen=True)
class PoseSample:
    """Where the object is: table position, heading (radians), resting face index, and an
    optional tilt out of that resting pose (``tilt`` radians about the horizontal axis at world
    heading ``tilt_dir``; the object is then lifted so that its lowest point touches the table,
    as if propped or held)."""

    x: float
    y: float
    yaw: float
    resting_index: int = 0
    tilt: float = 0.0
    tilt_dir: float = 0.0


def sample_pose(spec, sample: PoseSample, table_height: float) -> tuple[np.ndarray, np.ndarray]:
    """World position and quaternion (w, x, y, z) of ``spec`` placed as ``sample`` says."""
    from scorbot_gym.sim.simulation import quat_from_yaw, quat_mul, quat_to_mat

    rests = spec.resting_quats
    if not 0 <= sample.resting_index < len(rests):
        raise ValueError(
            f"resting_index must be in [0, {len(rests)}) for {spec.name}, "
            f"got {sample.resting_index}"
        )
    quat = quat_mul(quat_from_yaw(sample.yaw), np.asarray(rests[sample.resting_index], float))
    if sample.tilt:
        axis = np.array([np.cos(sample.tilt_dir), np.sin(sample.tilt_dir), 0.0])
        q_tilt = np.r_[np.cos(sample.tilt / 2), np.sin(sample.tilt / 2) * axis]
        quat = quat_mul(q_tilt, quat)
    lowest = (spec.mesh_vertices() @ quat_to_mat(quat).T)[:, 2].min()
    return np.array([sample.x, sample.y, table_height - lowest + 5e-4]), quat


@dataclass(frozen=True)
class LabelledView:
    """A rendered view with its ground truth (``camera_from_object``, 4x4, metres)."""

    view: View
    camera_from_object: np.ndarray
    world_from_object: np.ndarray
    occlusion: float  # fraction of the object's mask hidden by the occluder
    sample: PoseSample


def workspace_bounds() -> tuple[tuple[float, float], tuple[float, float]]:
    """The table area ``((xmin, xmax), (ymin, ymax))`` where objects are placed."""
    from scorbot_gym.sim.scene import WORKSPACE_X, WORKSPACE_Y

    return (tuple(WORKSPACE_X), tuple(WORKSPACE_Y))


def grid_poses(
    n_resting: int,
    yaw_step_deg: float = 10.0,
    xy_bounds: tuple[tuple[float, float], tuple[float, float]] = ((0.23, 0.33), (-0.1, 0.1)),
    n_positions: int = 2,
    seed: int = 0,
) -> list[PoseSample]:
    """Every resting face x every ``yaw_step_deg`` heading (the grid), each at ``n_positions``
    uniformly random table positions (the random part: positions vary continuously, so a
    position regressor sees more than a handful of places)."""
    if not 0 < yaw_step_deg <= 360:
        raise ValueError(f"yaw_step_deg must be in (0, 360], got {yaw_step_deg}")
    if n_resting < 1 or n_positions < 1:
        raise ValueError(
            f"need n_resting >= 1 and n_positions >= 1, got {n_resting}, {n_positions}"
        )
    rng = np.random.default_rng(seed)
    yaws = np.radians(np.arange(0.0, 360.0, yaw_step_deg))
    out = []
    for r in range(n_resting):
        for a in yaws:
            for _ in range(n_positions):
                x, y = rng.uniform(*xy_bounds[0]), rng.uniform(*xy_bounds[1])
                out.append(PoseSample(float(x), float(y), float(a), r))
    return out


def random_poses(
    n: int,
    n_resting: int,
    xy_bounds: tuple[tuple[float, float], tuple[float, float]],
    seed: int,
) -> list[PoseSample]:
    """``n`` uniformly random positions, headings and resting faces."""
    rng = np.random.default_rng(seed)
    return [
        PoseSample(
            float(rng.uniform(*xy_bounds[0])),
            float(rng.uniform(*xy_bounds[1])),
            float(rng.uniform(0.0, 2 * np.pi)),
            int(rng.integers(n_resting)),
        )
        for _ in range(n)
    ]


def occlude(
    image: np.ndarray, mask: np.ndarray, fraction: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, float]:
    """Paste a textured half-plane occluder hiding ``fraction`` of ``mask``'s pixels.

    The occluder's edge has a random direction; its offset is the quantile of the mask pixels'
    projections on that direction, so the hidden fraction is exact up to one pixel row. Returns
    the new image, the visible mask and the achieved fraction.
    """
    if not 0.0 <= fraction <= MAX_OCCLUSION:
        raise ValueError(f"occlusion must be within [0, {MAX_OCCLUSION}], got {fraction}")
    mask = np.asarray(mask, bool)
    n = int(mask.sum())
    if fraction == 0.0 or n == 0:
        return image, mask, 0.0
    theta = rng.uniform(0, 2 * np.pi)
    d = np.array([np.cos(theta), np.sin(theta)])
    ys, xs = np.nonzero(mask)
    proj = xs * d[0] + ys * d[1]
    cut = np.quantile(proj, 1.0 - fraction)
    h, w = mask.shape
    vv, uu = np.mgrid[0:h, 0:w]
    # Only near the object: a disc around it, so the occluder looks like a nearby object.
    cy, cx = ys.mean(), xs.mean()
    radius = 1.5 * np.sqrt(((xs - cx) ** 2 + (ys - cy) ** 2).max()) + 10
    occ = (uu * d[0] + vv * d[1] > cut) & ((uu - cx) ** 2 + (vv - cy) ** 2 < radius**2)
    out = image.copy()
    base = rng.integers(40, 200, 3)
    noise = rng.normal(0, 18, (h, w, 1))
    stripes = 25 * np.sign(np.sin((uu * d[1] - vv * d[0]) / rng.uniform(3, 8)))[..., None]
    patch = np.clip(base + noise + stripes, 0, 255).astype(np.uint8)
    out[occ] = patch[occ]
    visible = mask & ~occ
    return out, visible, 1.0 - visible.sum() / n


def _scene_fingerprint() -> str:
    """Hash of the source that decides what a render looks like (scene, objects, textures, this
    module): editing any of it invalidates the cache instead of serving stale images."""
    root = Path(__file__).resolve().parent.parent  # the scorbot_gym package
    files = [Path(__file__).resolve(), root / "objects.py", *sorted((root / "sim").glob("*.py"))]
    files += sorted((root / "assets").glob("*.py"))
    h = hashlib.sha256()
    for f in files:
        if f.is_file():
            h.update(f.name.encode() + f.read_bytes())
    return h.hexdigest()[:16]


def _cache_key(payload: dict) -> str:
    blob = json.dumps(payload, sort_keys=True).encode()
    return hashlib.sha256(blob).hexdigest()[:24]


def _file_stamp(path: str | None) -> list | None:
    if path is None or not Path(path).is_file():
        return None
    st = Path(path).stat()
    return [str(path), st.st_size, st.st_mtime_ns]


def render_views(
    object_name: str,
    samples: Sequence[PoseSample],
    camera: str = "top",
    width: int = 320,
    height: int = 240,
    occlusion: float | Sequence[float] = 0.0,
    seed: int = 0,
    cache_dir: str | os.PathLike | None = None,
    progress: bool = True,
    depth: bool = False,
    perturbation: Perturbation | None = None,
) -> list[LabelledView]:
    """Render (or read from the cache) one labelled view per pose sample.

    ``occlusion`` is one fraction for all views or one per view; occluders are drawn from
    ``seed``. ``depth=True`` also renders each view's depth (``View.depth``, metres along the
    optical axis; occluder pixels are set to 0, unknown). ``cache_dir=None`` uses
    ``$SCORBOT_GYM_CACHE`` or ``~/.cache/scorbot-gym``. ``perturbation`` draws view ``i``'s
    lighting, surfaces, camera error and image noise from its seed and ``i``
    (:mod:`scorbot_gym.data.perturbations`); the views' camera stays the nominal one.
    """
    from scorbot_gym.objects import get_object

    spec = get_object(object_name)
    samples = list(samples)
    occ = np.broadcast_to(np.asarray(occlusion, float), (len(samples),)).copy()
    if len(samples) == 0:
        raise ValueError("no pose samples to render")
    payload = {
        "version": CACHE_VERSION,
        "object": spec.name,
        "source": spec.source,
        "scale": spec.scale,
        "camera": camera,
        "size": [width, height],
        "samples": [[s.x, s.y, s.yaw, s.resting_index, s.tilt, s.tilt_dir] for s in samples],
        "occlusion": occ.tolist(),
        "seed": seed,
        "scene": _scene_fingerprint(),
        "texture": _file_stamp(spec.texture_path),
        "depth": bool(depth),
    }
    if perturbation is not None and perturbation.active:  # keys of unperturbed views unchanged
        payload["perturbation"] = perturbation.to_dict()
        payload["perturbation_code"] = perturbation_code_fingerprint()
    return cached_npz(
        cache_folder(cache_dir) / "views" / f"{_cache_key(payload)}.npz",
        lambda p: _load(p, spec.name, samples),
        lambda: _render(
            spec.name, samples, camera, width, height, occ, seed, progress, depth, perturbation
        ),
    )


def _render(
    name, samples, camera, width, height, occ, seed, progress, depth=False, perturbation=None
) -> dict:
    from scorbot_gym.sim import Simulation
    from scorbot_gym.sim.simulation import quat_to_mat

    sim = Simulation(object_name=name, render_width=width, render_height=height)
    perturber = ScenePerturber(sim)
    p = perturbation if perturbation is not None and perturbation.active else None
    rngs = np.random.default_rng(seed).spawn(len(samples))
    images, masks, depths, world_T, achieved = [], [], [], [], []
    try:
        for i, (s, f, rng) in enumerate(
            tqdm(
                list(zip(samples, occ, rngs, strict=True)),
                desc=f"render {name}",
                disable=not progress,
                leave=False,
            )
        ):
            pos, quat = sample_pose(sim.object_spec, s, sim.table_height)
            sim.set_object_pose(pos, quat)
            if p is not None and p.scene_active:
                perturber.apply(p, i)
            sim.forward()
            img = sim.render(camera)
            mask = sim.render(camera, kind="segmentation")
            occluded, visible, a = occlude(img, mask, float(f), rng)
            if depth:
                z = sim.render(camera, kind="depth")
                depths.append(np.where((occluded != img).any(axis=2), 0.0, z).astype(np.float32))
            img, mask = occluded, visible
            if p is not None:
                img = p.apply_image(img, i)
            images.append(img)
            masks.append(mask)
            achieved.append(a)
            world_T.append(np.r_[np.c_[quat_to_mat(quat), pos], [[0.0, 0.0, 0.0, 1.0]]])
        cam = perturber.nominal_camera_model(camera, width, height)
    finally:
        sim.close()
    out = {
        "images": np.array(images),
        "masks": np.array(masks),
        "world_from_object": np.array(world_T),
        "occlusion": np.array(achieved),
        "camera": np.array(json.dumps(cam.to_dict())),
    }
    if depth:
        out["depths"] = np.array(depths)
    return out


def _load(path: Path, name: str, samples: list[PoseSample]) -> list[LabelledView]:
    with np.load(path, allow_pickle=False) as z:
        cam = CameraModel.from_dict(json.loads(str(z["camera"])))
        images, masks, world_T, occ = (
            z["images"],
            z["masks"],
            z["world_from_object"],
            z["occlusion"],
        )
        depths = z["depths"] if "depths" in z.files else None
    if len(images) != len(samples):
        raise ValueError(f"cache entry {path} holds {len(images)} views, expected {len(samples)}")
    cam_from_world = cam.camera_from_world
    return [
        LabelledView(
            view=View(images[i], cam, masks[i], name, None if depths is None else depths[i]),
            camera_from_object=cam_from_world @ world_T[i],
            world_from_object=world_T[i],
            occlusion=float(occ[i]),
            sample=samples[i],
        )
        for i in range(len(samples))
    ]
