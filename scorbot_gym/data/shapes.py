"""Silhouettes of the catalogue objects rendered by the simulator, for shape recognition.

Each object rests on the table in one of its stable orientations, at a random heading and a
small random offset from the workspace centre, and is seen by one of a ring of 16 viewpoint
cameras (elevations 20/40/60 deg x azimuths -80..80 deg on a 0.5 m sphere around the
workspace centre, plus one straight above; all on the far side from the robot, so the parked
arm never occludes - checked by swinging the arm away and comparing masks). With
``viewpoints="scene"`` the scene's own ``top`` and ``side`` cameras are used instead and the
object may be anywhere in the workspace. The silhouette is the simulator's segmentation mask;
views where the object touches the image border or is tiny are redrawn.

Besides the mask, each sample carries ``extras["metric_size"]``: ``sqrt(mask area) * depth /
f`` in metres, the object's apparent physical size from the calibrated depth camera. Shape
descriptors are scale-invariant on purpose, so objects of one shape and different sizes (a
golf ball and a tennis ball) need this cue to be told apart.

Rendered sets are cached as compressed ``.npz`` under a content key in ``$SCORBOT_GYM_CACHE``
(default ``~/.cache/scorbot-gym``), written atomically.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from pose.fileio import UNREADABLE, atomic_savez, discard_cache_entry
from pose.shape.datasets import SilhouetteSet
from scorbot_gym._progress import ItemProgress
from scorbot_gym.data.views import default_cache_dir
from scorbot_gym.objects import CATALOGUE, get_object
from scorbot_gym.sim.cameras import CameraSpec
from scorbot_gym.sim.scene import DEFAULT_CAMERAS, TABLE_HEIGHT, WORKSPACE_X, WORKSPACE_Y

_CACHE_VERSION = 1
_CENTRE = (sum(WORKSPACE_X) / 2, sum(WORKSPACE_Y) / 2)
_TARGET = (_CENTRE[0], _CENTRE[1], TABLE_HEIGHT + 0.03)
ELEVATIONS_DEG = (20.0, 40.0, 60.0)
AZIMUTHS_DEG = (-80.0, -40.0, 0.0, 40.0, 80.0)  # 0 = on +x, looking back towards the robot
DISTANCE = 0.5
FOVY_DEG = 30.0
JITTER = 0.02  # metres around the workspace centre
MIN_PIXELS = 40


def viewpoint_cameras() -> tuple[CameraSpec, ...]:
    """The viewpoint ring: every (elevation, azimuth) pair plus one camera straight above."""
    cams = []
    for el in ELEVATIONS_DEG:
        for az in AZIMUTHS_DEG:
            e, a = np.deg2rad(el), np.deg2rad(az)
            offset = DISTANCE * np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
            pos = tuple(float(v) for v in np.add(_TARGET, offset))
            cams.append(CameraSpec(f"view_e{el:.0f}_a{az:+.0f}", pos, _TARGET, FOVY_DEG))
    above = (_TARGET[0], _TARGET[1], _TARGET[2] + DISTANCE)
    cams.append(CameraSpec("view_top", above, _TARGET, FOVY_DEG, up=(1.0, 0.0, 0.0)))
    return tuple(cams)


def scene_cameras() -> tuple[CameraSpec, ...]:
    """The scene's own fixed ``top`` and ``side`` cameras (``overview`` sees objects too small)."""
    return tuple(c for c in DEFAULT_CAMERAS if c.name in ("top", "side"))


VIEWPOINTS = {"ring": viewpoint_cameras, "scene": scene_cameras}


def _cache_key(objects, n_per_object: int, width: int, height: int, seed: int, viewpoints: str):
    specs = [
        {"name": o, "source": get_object(o).source, "scale": get_object(o).scale,
         "rests": [list(q) for q in get_object(o).resting_quats]}
        for o in objects
    ]  # fmt: skip
    cams = [[c.name, c.pos, c.target, c.fovy, c.up] for c in VIEWPOINTS[viewpoints]()]
    blob = json.dumps(
        [_CACHE_VERSION, specs, cams, n_per_object, width, height, seed, JITTER, MIN_PIXELS]
    )
    return hashlib.sha256(blob.encode()).hexdigest()[:20]


def _render_object(
    name: str, n: int, width: int, height: int, rng: np.random.Generator, viewpoints: str
) -> tuple[list, list, list, list]:
    from scorbot_gym.sim import Simulation  # imported late: it sets up OpenGL

    cams = VIEWPOINTS[viewpoints]()
    sim = Simulation(name, cameras=cams, render_width=width, render_height=height)
    try:
        masks, groups, sources, sizes = [], [], [], []
        rests = len(sim.object_spec.resting_quats)
        tries = 0
        while len(masks) < n:
            tries += 1
            if tries > 20 * n:
                raise RuntimeError(f"could not render {n} usable silhouettes of {name!r}")
            cam = cams[rng.integers(len(cams))].name
            rest = int(rng.integers(rests))
            yaw = float(rng.uniform(0, 2 * np.pi))
            if viewpoints == "scene":  # anywhere in the workspace, as the environment does
                xy = np.array([rng.uniform(*WORKSPACE_X), rng.uniform(*WORKSPACE_Y)])
            else:
                xy = np.add(_CENTRE, rng.uniform(-JITTER, JITTER, 2))
            sim.set_object_pose(*sim.resting_pose(xy, yaw, rest))
            sim.forward()
            mask = sim.render(cam, "segmentation")
            area = int(mask.sum())
            border = mask[0].any() or mask[-1].any() or mask[:, 0].any() or mask[:, -1].any()
            if area < MIN_PIXELS or border:
                continue
            depth = sim.render(cam, "depth")
            f = sim.camera_model(cam).K[0, 0]
            sizes.append(float(np.sqrt(area) * np.median(depth[mask]) / f))
            masks.append(mask)
            groups.append(cam)
            sources.append(f"{name}/{cam}/rest{rest}/yaw{np.rad2deg(yaw):.0f}")
        return masks, groups, sources, sizes
    finally:
        sim.close()


def silhouettes_path(
    objects: Sequence[str] | None = None,
    n_per_object: int = 60,
    width: int = 240,
    height: int = 180,
    seed: int = 0,
    viewpoints: str = "ring",
) -> Path:
    """Where :func:`render_catalogue_silhouettes` caches this set (keyed by all its inputs)."""
    objects = list(CATALOGUE) if objects is None else [get_object(o).name for o in objects]
    if n_per_object < 1:
        raise ValueError(f"n_per_object must be >= 1, got {n_per_object}")
    if viewpoints not in VIEWPOINTS:
        raise ValueError(f"viewpoints must be one of {', '.join(VIEWPOINTS)}, got {viewpoints!r}")
    key = _cache_key(objects, n_per_object, width, height, seed, viewpoints)
    return default_cache_dir() / f"silhouettes-{key}.npz"


def render_catalogue_silhouettes(
    objects: Sequence[str] | None = None,
    n_per_object: int = 60,
    width: int = 240,
    height: int = 180,
    seed: int = 0,
    use_cache: bool = True,
    viewpoints: str = "ring",
    progress: bool = False,
) -> SilhouetteSet:
    """Render ``n_per_object`` silhouettes of each object (default: the whole catalogue).

    Labels are object names, groups the camera names; everything random (camera, resting
    orientation, heading, offset) is drawn from ``seed``. ``viewpoints`` is ``"ring"`` (the
    viewpoint sphere, :func:`viewpoint_cameras`; object near the workspace centre) or
    ``"scene"`` (the scene's top and side cameras; object anywhere in the workspace).
    ``progress``: a bar (a line per object off a terminal) on stderr while rendering.
    """
    path = silhouettes_path(objects, n_per_object, width, height, seed, viewpoints)
    objects = list(CATALOGUE) if objects is None else [get_object(o).name for o in objects]
    if use_cache and path.is_file():
        try:
            with np.load(path, allow_pickle=False) as z:
                return SilhouetteSet(
                    list(z["masks"]), z["labels"], z["groups"], list(z["sources"]),
                    {"metric_size": z["metric_size"]},
                )  # fmt: skip
        except UNREADABLE as exc:
            discard_cache_entry(path, exc)
    rng = np.random.default_rng(seed)
    masks, labels, groups, sources, sizes = [], [], [], [], []
    desc = f"rendering silhouettes ({width}x{height})"
    with ItemProgress(desc, len(objects), enabled=progress) as bar:
        for name in objects:
            m, g, s, z = _render_object(name, n_per_object, width, height, rng, viewpoints)
            masks += m
            groups += g
            sources += s
            sizes += z
            labels += [name] * len(m)
            bar.update(name, f"{len(m)} silhouettes")
    data = SilhouetteSet(
        masks, np.array(labels), np.array(groups), sources, {"metric_size": np.array(sizes)}
    )
    if use_cache:
        _save_atomic(path, data)
    return data


def _save_atomic(path: Path, data: SilhouetteSet) -> None:
    atomic_savez(
        path, masks=np.stack(data.masks), labels=data.labels, groups=data.groups,
        sources=np.array(data.sources), metric_size=data.extras["metric_size"],
    )  # fmt: skip
