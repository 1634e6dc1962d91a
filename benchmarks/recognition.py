"""Object recognition vs occlusion: silhouette FLR (top, top + side), appearance, and both.

Target (issue 8): recognition at 50 % occlusion >= 95 %.

Test set: ``--per-object`` random poses of every catalogue object (random resting face,
heading and position in the workspace; seed ``--seed``), each seen by the scene's ``top`` and
``side`` cameras at 320 x 240. At each occlusion level a textured half-plane occluder
(:func:`scorbot_gym.data.views.occlude`, random direction) hides that fraction of the object's
mask, in both cameras independently. The recognisers see the occluded image and the visible
part of the mask (what a perfect segmenter would give):

- ``flr_top`` / ``flr_top_side``: :class:`pose.recognition.SilhouetteRecognizer` with one
  FLR per camera, trained (``scorbot_gym.perception.recognizers``) on 120 rendered
  scene-camera silhouettes per object (render seed 0, other poses than the test set's);
  ``top_side`` fuses both cameras' class costs;
- ``appearance_top``: :class:`pose.recognition.AppearanceRecognizer`: the object whose pose
  model (trained on the whole catalogue, top camera, 320 x 240) explains the most RANSAC
  inliers of the top view;
- ``flr_shortlist_appearance``: :class:`pose.recognition.ShortlistRecognizer`: the three best
  classes of ``flr_top_side``, decided among by appearance (``recognizer="flr+appearance"``).

Chance level is ``1 / n_objects``. Writes ``recognition.json`` and ``recognition.png``, by
default into a new ``runs/recognition-<time>/``. Run: ``MUJOCO_GL=egl python
benchmarks/recognition.py``; the committed record: ``... --out benchmarks/results/recognition.json
--overwrite`` (an existing ``--out`` is refused without ``--overwrite``).
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

import cv2
import numpy as np

from pose.fileio import atomic_write_json
from pose.recognition import ShortlistRecognizer
from pose.view import View
from scorbot_gym.data.shapes import scene_cameras
from scorbot_gym.data.views import occlude
from scorbot_gym.objects import CATALOGUE
from scorbot_gym.perception.recognizers import SHORTLIST_LENGTH, make_recognizer
from scorbot_gym.perception.training import train_models
from scorbot_gym.sim import Simulation
from scorbot_gym.sim.scene import WORKSPACE_X, WORKSPACE_Y

LEVELS = (0.0, 0.25, 0.5, 0.75)
MIN_PIXELS = 40


def sample_views(name: str, n: int, w: int, h: int, rng: np.random.Generator) -> list[dict]:
    """``n`` poses of ``name``, each as ``{cam: (rgb, mask, camera model)}``; objects cut by
    the image border in either camera are redrawn (as in the training silhouettes)."""
    sim = Simulation(name, cameras=scene_cameras(), render_width=w, render_height=h)
    out = []
    try:
        while len(out) < n:
            rest = int(rng.integers(len(sim.object_spec.resting_quats)))
            xy = (rng.uniform(*WORKSPACE_X), rng.uniform(*WORKSPACE_Y))
            sim.set_object_pose(*sim.resting_pose(xy, rng.uniform(0, 2 * np.pi), rest))
            sim.forward()
            views = {}
            for cam in ("top", "side"):
                mask = sim.render(cam, "segmentation")
                edge = mask[0].any() or mask[-1].any() or mask[:, 0].any() or mask[:, -1].any()
                if mask.sum() < MIN_PIXELS or edge:
                    break
                views[cam] = (sim.render(cam, "rgb"), mask, sim.camera_model(cam))
            if len(views) == 2:
                out.append(views)
    finally:
        sim.close()
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--objects", nargs="*", default=list(CATALOGUE))
    parser.add_argument("--per-object", type=int, default=20)
    parser.add_argument("--seed", type=int, default=1000)
    from scorbot_gym.experiments.outputs import Outputs, add_overwrite_option

    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        help="where to write (default: runs/recognition-<time>/recognition.json; an existing "
        "file is refused without --overwrite)",
    )
    add_overwrite_option(parser)
    args = parser.parse_args(argv)
    try:  # before any work: an existing file is not replaced unless asked
        args.out = Outputs("recognition", args.overwrite).path(
            args.out, "recognition.json", "--out", companions=[".png"]
        )
    except ValueError as exc:
        parser.error(str(exc))
    cv2.setNumThreads(1)
    w, h = 320, 240

    t0 = time.perf_counter()
    models, _ = train_models(args.objects, width=w, height=h, jobs=2, progress=False)
    flr = make_recognizer("flr", models, ("top", "side"), w, h)
    appearance = make_recognizer("appearance", models, ("top",), w, h)
    shortlist = ShortlistRecognizer(flr, appearance, SHORTLIST_LENGTH)
    setup_s = time.perf_counter() - t0

    rng = np.random.default_rng(args.seed)
    methods = ("flr_top", "flr_top_side", "appearance_top", "flr_shortlist_appearance")
    hits = {m: {lv: [] for lv in LEVELS} for m in methods}
    achieved = {lv: [] for lv in LEVELS}
    confusion = {m: {} for m in methods}
    ms = {m: [] for m in methods}
    for name in args.objects:
        for views in sample_views(name, args.per_object, w, h, rng):
            for level in LEVELS:
                seen = {}
                for cam, (rgb, mask, cm) in views.items():
                    img, visible, frac = occlude(rgb, mask, level, rng)
                    seen[cam] = (img, visible, cm)
                    achieved[level].append(frac)
                answers = {}
                t = time.perf_counter()
                answers["flr_top"] = flr.recognize({"top": seen["top"][1]}).label
                t1 = time.perf_counter()
                answers["flr_top_side"] = flr.recognize({c: v[1] for c, v in seen.items()}).label
                t2 = time.perf_counter()
                img, visible, cm = seen["top"]
                answers["appearance_top"] = appearance.recognize(View(img, cm, visible)).label
                t3 = time.perf_counter()
                masks = {c: v[1] for c, v in seen.items()}
                answers["flr_shortlist_appearance"] = shortlist.recognize(
                    masks, View(img, cm, visible)
                ).label
                t4 = time.perf_counter()
                for m, dt in zip(methods, (t1 - t, t2 - t1, t3 - t2, t4 - t3), strict=True):
                    ms[m].append(1e3 * dt)
                for m in methods:
                    hits[m][level].append(answers[m] == name)
                    if level == 0.5:
                        row = confusion[m].setdefault(name, {})
                        row[str(answers[m])] = row.get(str(answers[m]), 0) + 1
        right = {
            m: confusion[m][name].get(name, 0) / sum(confusion[m][name].values()) for m in methods
        }
        print(f"{name} at 50 %: " + ", ".join(f"{m} {v:.2f}" for m, v in right.items()))

    accuracy = {
        m: {f"{int(100 * lv)}%": float(np.mean(hits[m][lv])) for lv in LEVELS} for m in methods
    }
    chance = 1.0 / len(args.objects)
    report = {
        "date_utc": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "conditions": {
            "objects": args.objects,
            "poses_per_object": args.per_object,
            "seed": args.seed,
            "image": f"{w}x{h}",
            "occlusion": "textured half-plane occluder, both cameras independently",
            "achieved_occlusion_mean": {
                f"{int(100 * lv)}%": float(np.mean(achieved[lv])) for lv in LEVELS
            },
            "flr_training": "120 scene-camera silhouettes per object, render seed 0",
            "appearance_models": "train_models(all objects, top camera, 320x240)",
            "setup_s": round(setup_s, 1),
        },
        "target": "recognition at 50 % occlusion >= 95 %",
        "chance": chance,
        "accuracy": accuracy,
        "target_met": {m: bool(accuracy[m]["50%"] >= 0.95) for m in methods},
        "median_ms": {m: float(np.median(v)) for m, v in ms.items()},
        "confusion_at_50pct": confusion,
        "environment": {
            "python": sys.version.split()[0],
            "numpy": np.__version__,
            "opencv": cv2.__version__,
            "machine": platform.machine(),
        },
    }
    atomic_write_json(args.out, report)
    png = args.out.with_suffix(".png")
    _plot(accuracy, chance, png)
    for m in methods:
        print(
            m, {k: round(100 * v, 1) for k, v in accuracy[m].items()}, f"{np.median(ms[m]):.1f} ms"
        )
    print(f"chance {100 * chance:.1f} %; wrote {args.out} and {png}")
    return 0


def _plot(accuracy: dict, chance: float, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    x = [100 * lv for lv in LEVELS]
    for m, acc in accuracy.items():
        ax.plot(x, [100 * v for v in acc.values()], "o-", label=m)
    ax.axhline(100 * chance, color="grey", ls=":", label="chance")
    ax.axhline(95, color="grey", ls="--", lw=1)
    ax.set(xlabel="occlusion (% of the mask hidden)", ylabel="recognition accuracy (%)")
    ax.set_ylim(0, 102)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
