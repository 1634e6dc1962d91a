"""How far from a resting pose the default models put objects at rest and on a stand: the
measurement behind ``TableSupport.snap_deg`` (:mod:`scorbot_gym.perception.support`).

For each ``--tilts`` angle (0: resting on the table; >0: propped on the stand at that tilt), the
same seeded episodes as a closed-loop run start; the first valid estimate of each (the manifold
source with its defaults, the table-top prior off, the arm at home, a step or two at most) is
measured as ``TableSupport`` measures it: the symmetry-aware tilt out of the nearest resting
pose, and the slide along the top camera's line of sight that would put it on the table, with
the true height error beside it. Per tilt: quantiles, the share under each candidate threshold
and per object. Writes ``table_support.json``, by default into a new
``runs/table_support-<time>/`` (``--out`` names the file, an existing one only with
``--overwrite``).

    python benchmarks/table_support.py [--episodes 100] [--tilts 0 10] [--jobs 2]
    python benchmarks/table_support.py --out benchmarks/results/table_support.json --overwrite
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
os.environ.setdefault("MUJOCO_GL", "egl")

THRESHOLDS_DEG = (3.0, 5.0, 8.0, 10.0)


def first_estimates(tilt_deg: float, seed: int, episodes: int) -> list[dict]:
    """One row per episode with a valid estimate within its first 4 steps (a worker task)."""
    import numpy as np

    from pose.camera import CameraModel
    from scorbot_gym.evaluation.rollout import RolloutConfig
    from scorbot_gym.perception.base import WorldPose
    from scorbot_gym.perception.support import TableSupport

    # the models' own answers (the prior off), measured as the prior would measure them
    cfg = RolloutConfig(
        pose="manifold", episodes=episodes, seed=seed, tilt_deg=tilt_deg, support="none",
        calibration="none",
    )  # fmt: skip
    env = cfg.make_env()
    measure = TableSupport(snap_deg=90.0, max_shift_m=1.0)  # measures every estimate
    rows = []
    zero = np.zeros(env.action_space.shape, np.float32)
    for s in range(seed, seed + episodes):
        obs, info = env.reset(seed=s)
        for _ in range(4):
            if obs["pose_valid"][0] > 0.5:
                break
            obs, *_, info = env.step(zero)
        if obs["pose_valid"][0] < 0.5:
            continue
        cam = CameraModel(**info["camera_params"]["top"])
        est = WorldPose(
            np.asarray(obs["object_pos"], float),
            np.asarray(obs["object_quat"], float),
            True,
            object_name=info["object_name"],
            camera="top",
        )
        rec = measure.refine(est, cam).details["table_support"]
        true_z = float(info["object_pose"]["position"][2])
        rows.append(
            {
                "seed": s,
                "object": info["object_name"],
                "tilt_deg": round(rec["tilt_deg"], 3),
                "slide_mm": round(rec["shift_mm"], 2),
                "height_error_mm": round(1e3 * (est.position[2] - true_z), 2),
            }
        )
    env.close()
    return rows


def summarize_tilt(rows: list[dict]) -> dict:
    import numpy as np

    t = np.array([r["tilt_deg"] for r in rows])
    out = {
        "estimates": len(rows),
        "tilt_deg_quantiles": dict(
            zip(
                ("p10", "p50", "p90", "p95"),
                np.percentile(t, [10, 50, 90, 95]).round(2).tolist(),
                strict=True,
            )
        ),
        "share_under_deg": {f"{th:g}": round(float((t < th).mean()), 4) for th in THRESHOLDS_DEG},
        "median_abs_height_error_mm": round(
            float(np.median([abs(r["height_error_mm"]) for r in rows])), 2
        ),
        "per_object_median_tilt_deg": {},
    }
    for name in sorted({r["object"] for r in rows}):
        out["per_object_median_tilt_deg"][name] = round(
            float(np.median([r["tilt_deg"] for r in rows if r["object"] == name])), 2
        )
    out["rows"] = rows
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=100, help="per tilt")
    ap.add_argument("--tilts", type=float, nargs="+", default=[0.0, 10.0])
    ap.add_argument("--seed", type=int, default=1000, help="first seed of tilt 0 (+1000 a tilt)")
    ap.add_argument("--jobs", type=int, default=1)
    from scorbot_gym.experiments.outputs import Outputs, add_overwrite_option

    ap.add_argument(
        "--out",
        type=Path,
        default=None,
        help="where to write (default: runs/table_support-<time>/table_support.json; an existing "
        "file is refused without --overwrite)",
    )
    add_overwrite_option(ap)
    args = ap.parse_args(argv)
    try:  # before any work: an existing file is not replaced unless asked
        args.out = Outputs("table_support", args.overwrite).path(
            args.out, "table_support.json", "--out", companions=[".png"]
        )
    except ValueError as exc:
        ap.error(str(exc))
    if args.episodes < 1 or args.jobs < 1 or any(t < 0 or t > 45 for t in args.tilts):
        ap.error("--episodes and --jobs must be >= 1, --tilts in [0, 45] degrees")

    from pose.fileio import atomic_write_json
    from scorbot_gym.perception.training import default_pose_models

    default_pose_models("top", 320, 240)  # trained once here, not by every worker at once
    half = (args.episodes + 1) // 2
    tasks = []
    for i, tilt in enumerate(args.tilts):
        seed = args.seed + 1000 * i
        tasks += [(tilt, seed, half), (tilt, seed + half, args.episodes - half)]
    t0 = time.perf_counter()
    if args.jobs > 1:
        from scorbot_gym.experiments.workers import worker_pool

        with worker_pool(args.jobs) as pool:
            chunks = list(pool.map(first_estimates, *zip(*tasks, strict=True)))
    else:
        chunks = [first_estimates(*t) for t in tasks]
    by_tilt: dict[str, list] = {}
    for (tilt, _, _), rows in zip(tasks, chunks, strict=True):
        by_tilt.setdefault(f"{tilt:g}", []).extend(rows)
    report = {
        "benchmark": "table_support",
        "episodes_per_tilt": args.episodes,
        "seed": args.seed,
        "tilts": {k: summarize_tilt(v) for k, v in by_tilt.items()},
        "wall_s": round(time.perf_counter() - t0, 1),
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count(), "jobs": args.jobs},
    }
    for k, v in report["tilts"].items():
        print(f"tilt {k:>3} deg: {v['estimates']} estimates, tilt quantiles "
              f"{v['tilt_deg_quantiles']}, share under {v['share_under_deg']}")  # fmt: skip
    atomic_write_json(args.out, report)
    print(f"written {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
