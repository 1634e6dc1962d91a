"""Write rendered test views, their ground truth and estimates in the BOP format.

So that the BOP toolkit (``bop_toolkit_lib``) can score our estimators with its own metrics
(VSD, MSSD, MSPD), an ablation's test views are written as a BOP dataset::

    DIR/models/obj_000001.ply, models_info.json     (millimetres, with symmetries)
    DIR/test/000001/rgb/000000.png, depth/..., mask_visib/000000_000000.png
    DIR/test/000001/scene_camera.json               cam_K, depth_scale, cam_R_w2c, cam_t_w2c
    DIR/test/000001/scene_gt.json                   cam_R_m2c, cam_t_m2c (mm), obj_id
    DIR/test/000001/scene_gt_info.json              bbox_visib, px_count_visib, visib_fract
    DIR/test_targets_bop19.json                     im_id, inst_count, obj_id, scene_id
    DIR/METHOD_DATASET-test.csv                     scene_id,im_id,obj_id,score,R,t,time

One scene per (object, occlusion level); ``scenes.json`` says which. Rotations are row-major
3x3, translations millimetres, ``time`` seconds per image (the toolkit's conventions).
Object ids are 1-based positions in the catalogue (``obj_ids.json``).
"""

from __future__ import annotations

import csv
import io
import os
import re
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from pose.fileio import atomic_write_bytes, atomic_write_json

DEPTH_SCALE = 0.1  # depth PNG unit in mm (uint16: up to 6.5 m)
CSV_FIELDS = ("scene_id", "im_id", "obj_id", "score", "R", "t", "time")


def object_ids() -> dict[str, int]:
    from scorbot_gym.objects import object_names

    return {n: i + 1 for i, n in enumerate(object_names())}


def method_name(label: str) -> str:
    """A BOP method name (no underscores: the toolkit splits file names on them)."""
    return re.sub(r"[^A-Za-z0-9]+", "-", label).strip("-") or "method"


def _png(image: np.ndarray) -> bytes:
    img = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
    ok, buf = cv2.imencode(".png", img)
    if not ok:
        raise ValueError("could not encode PNG")
    return buf.tobytes()


def _flat(a) -> list[float]:
    return [float(v) for v in np.asarray(a, float).ravel()]


def write_models(root: str | os.PathLike, names: Sequence[str]) -> None:
    """PLY meshes in mm and ``models_info.json`` (diameter, extent, symmetries)."""
    import trimesh

    from scorbot_gym.objects import get_object

    ids, info = object_ids(), {}
    for name in names:
        spec = get_object(name)
        m = spec.model
        v = np.asarray(m.vertices, float) * 1000.0
        ply = trimesh.Trimesh(v, m.faces, process=False).export(file_type="ply", encoding="ascii")
        atomic_write_bytes(Path(root) / "models" / f"obj_{ids[name]:06d}.ply", ply)
        lo, hi = v.min(0), v.max(0)
        hull = trimesh.Trimesh(v, m.faces, process=False).convex_hull.vertices
        diam = max(float(np.linalg.norm(hull[:, None] - hull[None], axis=2).max()), 0.0)
        e = {"diameter": diam, "min_x": lo[0], "min_y": lo[1], "min_z": lo[2],
             "size_x": hi[0] - lo[0], "size_y": hi[1] - lo[1], "size_z": hi[2] - lo[2]}  # fmt: skip
        sym = spec.symmetry
        if sym.kind == "axial":
            e["symmetries_continuous"] = [{"axis": list(sym.axis), "offset": [0, 0, 0]}]
        elif sym.kind == "discrete":
            e["symmetries_discrete"] = [
                _flat(np.r_[np.c_[R, np.zeros(3)], [[0, 0, 0, 1]]]) for R in sym.rotations()[1:]
            ]
        info[str(ids[name])] = {k: float(x) if not isinstance(x, list) else x for k, x in e.items()}
    atomic_write_json(Path(root) / "models" / "models_info.json", info)


def write_scene(scene_dir: str | os.PathLike, views: Sequence, obj_id: int) -> None:
    """One scene: a :class:`~scorbot_gym.data.views.LabelledView` per image, one object each."""
    d = Path(scene_dir)
    cams, gts, infos = {}, {}, {}
    for i, lv in enumerate(views):
        v = lv.view
        atomic_write_bytes(d / "rgb" / f"{i:06d}.png", _png(v.image))
        if v.depth is not None:
            z = np.round(np.asarray(v.depth, float) * 1000.0 / DEPTH_SCALE)
            # beyond the PNG's range (the far plane behind the table) is unknown, 0 in BOP:
            # a saturated value would be a wrong depth, not a missing one
            z[~np.isfinite(z) | (z < 0) | (z > 65535)] = 0
            atomic_write_bytes(d / "depth" / f"{i:06d}.png", _png(z.astype(np.uint16)))
        mask = np.zeros(v.image.shape[:2], bool) if v.mask is None else np.asarray(v.mask, bool)
        atomic_write_bytes(
            d / "mask_visib" / f"{i:06d}_000000.png", _png(mask.astype(np.uint8) * 255)
        )
        c2w = v.camera.camera_from_world
        cams[str(i)] = {
            "cam_K": _flat(v.camera.K),
            "depth_scale": DEPTH_SCALE,
            "cam_R_w2c": _flat(c2w[:3, :3]),
            "cam_t_w2c": _flat(c2w[:3, 3] * 1000.0),
        }
        T = lv.camera_from_object
        gts[str(i)] = [
            {"cam_R_m2c": _flat(T[:3, :3]), "cam_t_m2c": _flat(T[:3, 3] * 1000.0), "obj_id": obj_id}
        ]
        x, y, w, h = cv2.boundingRect(mask.astype(np.uint8)) if mask.any() else (-1, -1, -1, -1)
        infos[str(i)] = [
            {"bbox_visib": [x, y, w, h], "px_count_visib": int(mask.sum()),
             "visib_fract": round(1.0 - float(lv.occlusion), 4)}
        ]  # fmt: skip
    atomic_write_json(d / "scene_camera.json", cams)
    atomic_write_json(d / "scene_gt.json", gts)
    atomic_write_json(d / "scene_gt_info.json", infos)


def write_results(path: str | os.PathLike, rows: Sequence[dict]) -> None:
    """A BOP results CSV: rows with ``scene_id, im_id, obj_id, score, R`` (3x3), ``t`` (mm),
    ``time`` (s). Invalid estimates are left out, as the toolkit expects."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(CSV_FIELDS)
    for r in rows:
        R, t = np.asarray(r["R"], float), np.asarray(r["t"], float)
        if not (np.isfinite(R).all() and np.isfinite(t).all()):
            continue
        w.writerow([
            int(r["scene_id"]), int(r["im_id"]), int(r["obj_id"]), f"{float(r['score']):.6f}",
            " ".join(f"{v:.8f}" for v in R.ravel()), " ".join(f"{v:.4f}" for v in t.ravel()),
            f"{float(r['time']):.6f}",
        ])  # fmt: skip
    atomic_write_bytes(path, buf.getvalue().encode())


def export_ablation(
    report: dict, root: str | os.PathLike, dataset: str = "scorbot", cache_dir: str | None = None
) -> Path:
    """Write an :func:`~scorbot_gym.experiments.ablate` report's test views and every
    estimator's answers as a BOP dataset under ``root``; returns ``root``."""
    from scorbot_gym.data.perturbations import Perturbation
    from scorbot_gym.data.protocols import held_out_views

    root = Path(root)
    spec, trials = report["spec"], report["trials"]
    ids = object_ids()
    pairs = sorted({(t["object"], t["occlusion"]) for t in trials})
    scene_of = {p: i + 1 for i, p in enumerate(pairs)}
    pert = Perturbation(**spec["perturbation"])
    write_models(root, sorted({o for o, _ in pairs}))
    targets = []
    for (obj, occ), sid in scene_of.items():
        views = held_out_views(
            spec["protocol"], obj, occ, width=spec["width"], height=spec["height"],
            seed=spec["seed"] + 1, cache_dir=cache_dir, perturbation=pert,
        )[: spec["test_views"]]  # fmt: skip
        write_scene(root / "test" / f"{sid:06d}", views, ids[obj])
        targets += [
            {"im_id": i, "inst_count": 1, "obj_id": ids[obj], "scene_id": sid}
            for i in range(len(views))
        ]
    atomic_write_json(root / "test_targets_bop19.json", targets)
    atomic_write_json(
        root / "scenes.json",
        {str(s): {"object": o, "occlusion": occ, "protocol": spec["protocol"]}
         for (o, occ), s in scene_of.items()},
    )  # fmt: skip
    atomic_write_json(root / "obj_ids.json", ids)
    for label in dict.fromkeys(t["estimator"] for t in trials):
        rows = []
        for t in (t for t in trials if t["estimator"] == label):
            v = t["views"]
            sid = scene_of[(t["object"], t["occlusion"])]
            for i in range(len(v["R"])):
                R = np.array(v["R"][i], dtype=float)  # None (invalid) entries become NaN
                rows.append({
                    "scene_id": sid, "im_id": i, "obj_id": ids[t["object"]],
                    "score": v["score"][i] or 0.0, "R": R,
                    "t": np.array(v["t"][i], dtype=float) * 1000.0,
                    "time": (v["ms"][i] or 0.0) / 1000.0,
                })  # fmt: skip
        write_results(root / f"{method_name(label)}_{dataset}-test.csv", rows)
    return root
