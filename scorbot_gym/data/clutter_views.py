"""Labelled views of a target among real occluders: the ``clutter`` protocol's test views.

The other protocols hide a requested fraction of the object behind a pasted half-plane. Here the
occluders are other catalogue objects on the table, rendered with the target: each view puts the
target in its sampled pose and ``distractors`` other objects (drawn from the catalogue) in
resting poses around it, some on the camera's side of it, where they hide part of it. How much
is hidden is **measured** from the segmentation: the target's mask with the distractors shown
against its mask with them hidden (``1 - visible / unoccluded`` pixels), so the occlusion axis
of a ``clutter`` curve is what the camera saw, not a knob. The view's mask is the target's
visible mask, as in every protocol (the estimators are scored on the pose, given the object's
pixels; splitting a cluttered foreground into objects is the closed loop's job).

Footprints are kept apart by their bounding circles (plus a clearance), so no two objects
interpenetrate and none needs physics to settle. Every draw comes from ``seed`` (one generator
per view). Renders are cached like :func:`~scorbot_gym.data.views.render_views`' (content key,
atomic write, unreadable entries discarded and rendered again).
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Sequence
from functools import lru_cache
from pathlib import Path

import numpy as np
from tqdm import tqdm

from pose.fileio import cached_npz
from scorbot_gym.data import cache_folder
from scorbot_gym.data.views import (
    MAX_OCCLUSION,
    LabelledView,
    PoseSample,
    _cache_key,
    _file_stamp,
    _load,
    _scene_fingerprint,
    sample_pose,
)

CLUTTER_VERSION = 1
CLEARANCE = 0.005  # m between the bounding circles of two objects' footprints
EXTRA_GAP = (0.0, 0.04)  # m added to the touching distance of a distractor from the target
TOWARD_CAMERA = 0.6  # share of distractors drawn on the camera's side of the target (within 50°)
_TRIES = 60


@lru_cache(maxsize=1)
def code_fingerprint() -> str:
    """Hash of this module: what a clutter view looks like (the trial cache keys on it)."""
    return hashlib.sha256(Path(__file__).read_bytes()).hexdigest()[:16]


def _radius(name: str) -> float:
    """Radius (m) of the object's footprint's bounding circle, any resting pose or heading."""
    from scorbot_gym.objects import get_object

    return float(np.linalg.norm(get_object(name).mesh_vertices(), axis=1).max())


def measured_occlusion(visible: np.ndarray, unoccluded: np.ndarray) -> float:
    """The share of the target's unoccluded mask that is not visible (0 for an empty mask)."""
    n = int(np.count_nonzero(unoccluded))
    if n == 0:
        return 0.0
    return float(1.0 - np.count_nonzero(np.asarray(visible, bool) & unoccluded) / n)


def render_clutter_views(
    object_name: str,
    samples: Sequence[PoseSample],
    camera: str = "side",
    width: int = 320,
    height: int = 240,
    distractors: int = 3,
    seed: int = 0,
    cache_dir: str | os.PathLike | None = None,
    progress: bool = False,
) -> list[LabelledView]:
    """One view per pose sample of ``object_name`` among ``distractors`` other catalogue
    objects; each view's ``occlusion`` is measured from the segmentation (see the module
    docstring)."""
    from scorbot_gym.objects import get_object, object_names

    spec = get_object(object_name)
    samples = list(samples)
    if not samples:
        raise ValueError("no pose samples to render")
    pool = sorted(n for n in object_names() if n != spec.name)
    if not 0 <= distractors <= len(pool):
        raise ValueError(f"distractors must be within [0, {len(pool)}], got {distractors}")
    payload = {
        "kind": "clutter",
        "version": CLUTTER_VERSION,
        "object": spec.name,
        "source": spec.source,
        "scale": spec.scale,
        "camera": camera,
        "size": [width, height],
        "samples": [[s.x, s.y, s.yaw, s.resting_index, s.tilt, s.tilt_dir] for s in samples],
        "distractors": distractors,
        "pool": pool,
        "seed": seed,
        "scene": _scene_fingerprint(),
        "code": code_fingerprint(),
        "texture": _file_stamp(spec.texture_path),
    }
    return cached_npz(
        cache_folder(cache_dir) / "views" / f"clutter-{_cache_key(payload)}.npz",
        lambda p: _load(p, spec.name, samples),
        lambda: _render(
            spec.name, samples, camera, width, height, distractors, pool, seed, progress
        ),
    )


def _render(name, samples, camera, width, height, k, pool, seed, progress) -> dict:
    from scorbot_gym.sim import Simulation
    from scorbot_gym.sim.simulation import quat_to_mat

    rngs = np.random.default_rng(seed).spawn(len(samples))
    chosen = [sorted(r.choice(pool, size=k, replace=False).tolist()) for r in rngs]
    used = sorted({n for c in chosen for n in c})
    sim = Simulation(object_name=name, render_width=width, render_height=height, others=used)
    radius = {n: _radius(n) for n in [name, *used]}
    images, masks, world_T, achieved, layouts = [], [], [], [], []
    try:
        cam_xy = sim.camera_model(camera).world_from_camera[:2, 3]
        for s, names, rng in tqdm(
            list(zip(samples, chosen, rngs, strict=True)),
            desc=f"render {name} in clutter", disable=not progress, leave=False,
        ):  # fmt: skip
            sim.reset()  # every object parked and hidden
            sim.unpark(name)
            pos, quat = sample_pose(sim.object_spec, s, sim.table_height)
            sim.set_pose_of(name, pos, quat)
            placed = _place(sim, rng, name, pos[:2], names, radius, cam_xy)
            sim.forward()
            img = sim.render(camera)
            visible = sim.render(camera, kind="segmentation")
            sim.set_objects_visible(placed, False)
            unoccluded = sim.render(camera, kind="segmentation")
            images.append(img)
            masks.append(visible)
            achieved.append(measured_occlusion(visible, unoccluded))
            world_T.append(np.r_[np.c_[quat_to_mat(quat), pos], [[0.0, 0.0, 0.0, 1.0]]])
            layouts.append(placed)
        cam = sim.camera_model(camera)
    finally:
        sim.close()
    return {
        "images": np.array(images),
        "masks": np.array(masks),
        "world_from_object": np.array(world_T),
        "occlusion": np.array(achieved),
        "camera": np.array(json.dumps(cam.to_dict())),
        "distractor_names": np.array(json.dumps(layouts)),
    }


def _place(sim, rng, target, target_xy, names, radius, cam_xy) -> list[str]:
    """Put each of ``names`` resting near the target, footprints apart; returns those placed
    (a distractor with no free spot in ``_TRIES`` draws is left off the table)."""
    toward = float(np.arctan2(*(cam_xy - target_xy)[::-1]))
    circles = [(np.asarray(target_xy, float), radius[target])]
    placed = []
    for n in names:
        rests = len(sim.objects[n].spec.resting_quats)
        for _ in range(_TRIES):
            if rng.random() < TOWARD_CAMERA:
                a = toward + rng.uniform(-np.radians(50), np.radians(50))
            else:
                a = rng.uniform(-np.pi, np.pi)
            r = radius[target] + radius[n] + CLEARANCE + rng.uniform(*EXTRA_GAP)
            xy = np.asarray(target_xy, float) + r * np.array([np.cos(a), np.sin(a)])
            apart = all(np.linalg.norm(xy - c) >= rc + radius[n] + CLEARANCE for c, rc in circles)
            if apart:
                p, q = sim.resting_pose(xy, float(rng.uniform(-np.pi, np.pi)),
                                        int(rng.integers(rests)), name=n)  # fmt: skip
                sim.unpark(n)
                sim.set_pose_of(n, p, q)
                circles.append((xy, radius[n]))
                placed.append(n)
                break
    return placed


def occlusion_bin(occlusion: float, edges: Sequence[float]) -> float | None:
    """The lower edge of the bin ``[edge, next edge)`` holding ``occlusion`` (the last bin ends
    at :data:`~scorbot_gym.data.views.MAX_OCCLUSION`; a target hidden more than that is in
    none: there is nothing left to estimate from)."""
    edges = sorted(edges)
    if occlusion >= MAX_OCCLUSION:
        return None
    below = [e for e in edges if e <= occlusion + 1e-9]
    return below[-1] if below else None
