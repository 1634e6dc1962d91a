"""Blob splitting on rendered tables where two objects touch (issue 37, item 2).

In the closed loop, objects share a blob in few first views (the placer keeps footprints a
few millimetres apart and gaps of 3-15 cm), so success there says little about the splitter
itself. This benchmark makes the case it exists for: per seed, the env's seeded table (a
drawn target + ``--distractors`` from the catalogue, 320 x 240 top camera), then one distractor
slid against the target until they touch (backed off 2 mm: no interpenetration). Background
subtraction (minus the arm) gives the components; the simulator's per-object masks (scoring
only) say which objects each holds. Every splitter (:mod:`scorbot_gym.perception.splitters`)
splits the same components:

- on components holding two or more objects (each >= ``MIN_VISIBLE`` px): whether it gave
  one region per object, each matching its object (IoU >= ``GOOD_IOU``), the mean best IoU,
  and whether the keypoint splitter's region labels are the objects' classes;
- on components of one object: how often it was (wrongly) split;
- the time of a full split of all components of a view, and of the remembered split
  (:class:`pose.splitting.SplitMemory`, the same view again: what most closed-loop steps pay).

Writes ``blob_split.json`` (medians, rates; no per-view arrays), by default into a new
``runs/blob_split-<time>/``; ``--out`` names the file (an existing one only with ``--overwrite``).

    python benchmarks/blob_split.py --scenes 200
    python benchmarks/blob_split.py --scenes 200 --out benchmarks/results/blob_split.json \\
        --overwrite   # the committed record
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one core: the times are one-core times
os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402

MIN_VISIBLE = 100  # px of an object inside a component for it to count as held by it
GOOD_IOU = 0.7


def true_masks(sim, camera: str, names: list[str]) -> dict[str, np.ndarray]:
    """Each object's visible pixels (the simulator's segmentation: for scoring only)."""
    import mujoco

    out = sim.renderer.render(sim.model, sim.data, sim.camera_id(camera), "segmentation",
                              sim.render_width, sim.render_height)  # fmt: skip
    is_geom = out[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM)
    return {n: is_geom & np.isin(out[..., 0], sim.objects[n].geoms) for n in names}


def score_view(regions, comps, truth) -> dict[str, list]:
    """Per component: the objects it holds, and how the splitter's regions match them."""
    out: dict[str, list] = {"shared_ok": [], "shared_iou": [], "shared_labels": [], "single": []}
    for i, comp in enumerate(comps):
        held = [n for n, m in truth.items() if (comp & m).sum() >= MIN_VISIBLE]
        parts = [r for r in regions if r.component == i]
        if len(held) < 2:
            out["single"].append(len(parts) > 1)  # over-split
            continue
        ious = np.array(
            [[(r.mask & truth[n]).sum() / max((r.mask | truth[n]).sum(), 1) for r in parts]
             for n in held]
        )  # fmt: skip
        best = ious.max(axis=1)
        owner = ious.argmax(axis=1)
        one_to_one = len(parts) == len(held) and len(set(owner.tolist())) == len(held)
        out["shared_ok"].append(bool(one_to_one and (best >= GOOD_IOU).all()))
        out["shared_iou"].append(float(best.mean()))
        labels = [parts[j].label == n for n, j in zip(held, owner, strict=True)]
        out["shared_labels"].append(float(np.mean(labels)))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=int, default=200, help="seeded tables (one per seed)")
    ap.add_argument("--seed", type=int, default=7000, help="first table's seed")
    ap.add_argument("--distractors", type=int, default=2)
    from scorbot_gym.experiments.outputs import Outputs, add_overwrite_option

    ap.add_argument(
        "--out",
        type=Path,
        default=None,
        help="where to write (default: runs/blob_split-<time>/blob_split.json; an existing "
        "file is refused without --overwrite)",
    )
    add_overwrite_option(ap)
    args = ap.parse_args(argv)
    try:  # before any work: an existing file is not replaced unless asked
        args.out = Outputs("blob_split", args.overwrite).path(
            args.out, "blob_split.json", "--out", companions=[".png"]
        )
    except ValueError as exc:
        ap.error(str(exc))
    if args.scenes < 1 or args.distractors < 1:
        ap.error("--scenes and --distractors must be >= 1")

    import cv2

    from pose.camera import CameraModel
    from pose.fileio import atomic_write_json
    from pose.splitting import SplitMemory
    from scorbot_gym.envs.factory import make_env
    from scorbot_gym.names import SPLITTERS
    from scorbot_gym.perception import make_pose_source
    from scorbot_gym.perception.base import PerceptionFrame
    from scorbot_gym.perception.splitters import make_splitter
    from scorbot_gym.perception.training import default_pose_models
    from scorbot_gym.tasks.clutter import slide_into_contact

    cv2.setNumThreads(1)
    models = default_pose_models("top", 320, 240)
    splitters = {name: make_splitter(name, models) for name in SPLITTERS}
    if isinstance(splitters["keypoints"], SplitMemory):  # timed without and with the memory
        memory, splitters["keypoints"] = splitters["keypoints"], splitters["keypoints"].splitter
    env = make_env("ScorbotGrasp-v0", pose="manifold_clutter", pose_kwargs={"models": models},
                   distractors=args.distractors)  # fmt: skip
    inner = env.env  # under the pose wrapper: its observation holds the images
    # its segmenter only (appearance: no recogniser to train)
    source = make_pose_source("manifold_clutter", models=models, recognizer="appearance")
    scores = {name: {"shared_ok": [], "shared_iou": [], "shared_labels": [], "single": [],
                     "ms": []} for name in splitters}  # fmt: skip
    remembered_ms, skipped = [], 0
    t0 = time.perf_counter()
    for seed in range(args.seed, args.seed + args.scenes):
        obs, info = inner.reset(seed=seed)
        target = info["object_name"]
        cams = {n: CameraModel(**p) for n, p in info["camera_params"].items()}
        backgrounds = dict(info["camera_background"])
        frame = PerceptionFrame(obs, cams, target, backgrounds=backgrounds)
        source.reset(frame, np.random.default_rng(seed))
        sim = inner.unwrapped.sim
        neighbour = next(n for n in info["objects"] if n != target)
        if not slide_into_contact(sim, neighbour, target):
            skipped += 1
            continue
        obs, *_, info = inner.step(np.zeros(6, np.float32))
        frame = PerceptionFrame(obs, cams, target, step=1, backgrounds=backgrounds)
        comps = source.segmenter.blobs(frame, "top")
        image = np.asarray(obs["top_rgb"])
        truth = true_masks(sim, "top", list(info["objects"]))
        for name, splitter in splitters.items():
            t = time.perf_counter()
            regions = splitter.split(image, comps, cams["top"])
            scores[name]["ms"].append(1e3 * (time.perf_counter() - t))
            for k, v in score_view(regions, comps, truth).items():
                scores[name][k] += v
        memory.reset()
        memory.split(image, comps, cams["top"])
        t = time.perf_counter()
        memory.split(image, comps, cams["top"])
        remembered_ms.append(1e3 * (time.perf_counter() - t))
    env.close()

    def rate(v: list) -> float | None:
        return float(np.mean(v)) if v else None

    report = {
        "scenes": args.scenes,
        "skipped_scenes": skipped,
        "seed": args.seed,
        "distractors": args.distractors,
        "min_visible_px": MIN_VISIBLE,
        "good_iou": GOOD_IOU,
        "splitters": {
            name: {
                "shared_components": len(s["shared_ok"]),
                "shared_split_correctly": rate(s["shared_ok"]),
                "shared_mean_best_iou": rate(s["shared_iou"]),
                "shared_region_labels_correct": rate(s["shared_labels"])
                if name == "keypoints"
                else None,
                "single_object_components": len(s["single"]),
                "single_object_over_split": rate(s["single"]),
                "median_ms_per_view": float(np.median(s["ms"])) if s["ms"] else None,
            }
            for name, s in scores.items()
        },  # fmt: skip
        "keypoints_remembered_median_ms_per_view": (
            float(np.median(remembered_ms)) if remembered_ms else None
        ),
        "wall_s": time.perf_counter() - t0,
        "machine": {
            "platform": platform.platform(),
            "cpus": os.cpu_count(),
            "load_average_1min_at_end": os.getloadavg()[0],
        },
    }
    for name, s in report["splitters"].items():
        print(
            f"{name:>10}: shared components {s['shared_components']}, split correctly "
            f"{s['shared_split_correctly']}, mean IoU {s['shared_mean_best_iou']}, single "
            f"over-split {s['single_object_over_split']}, {s['median_ms_per_view']} ms/view"
        )
    print(f"keypoints remembered: {report['keypoints_remembered_median_ms_per_view']} ms/view")
    atomic_write_json(args.out, report)
    print(f"written {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
