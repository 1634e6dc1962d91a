"""Closed-loop grasping of a named target on a cluttered table (issue 37, item 2).

Every arm runs the same seeded episodes: the target drawn from the catalogue, ``--distractors``
other catalogue objects drawn beside it (seeded, close enough to touch and occlude), the
scripted controller re-planning from every estimate. The arms differ by one component, the
pose source (:mod:`scorbot_gym.perception.registry`):

- ``oracle``: the target's true pose (the ceiling; privileged);
- ``manifold_clutter``: background subtraction split into blobs, every blob recognised (FLR
  shortlist + appearance), the target's pose estimated on its blob by the default top-camera
  pose models; no privileged input, the target named by the task command;
- ``largest_blob``: the same blobs and models, the largest blob taken (no recognition): the
  baseline of a single-object pipeline;
- ``random_blob``: the same, a blob drawn at random (the chance level: grasp a random blob).

Episodes are cut into chunks that run in ``--jobs`` processes (each builds its env once per
chunk); the summary pools every chunk's episodes, so the figures do not depend on ``--jobs``.
Writes ``clutter_closed_loop.json``, into a new ``runs/clutter_closed_loop-<time>/`` unless
``--out`` names a file (an existing one only with ``--overwrite``) (the main run at its top
level; ``--config NAME`` stores a variant, e.g. another splitter or seed range, as
``configs[NAME]``, the file's other runs left as they were; ``--quick`` the config ``quick``): per
distractor count and arm the rollout summary (success with its 95 % interval, failure causes
with ``wrong_object``, distractors knocked over, perception: target recognition accuracy, blob
recognition, errors, the in-loop cost per estimate and per stage), one line per failed episode
(seed, target, cause) to find the failures behind a number, the issue's targets met or not, and
(for the main run) a PNG.

    python benchmarks/clutter_closed_loop.py --episodes 200 --distractors 0 2 4 --jobs 16
    python benchmarks/clutter_closed_loop.py --episodes 200 --distractors 2 --jobs 2 \\
        --arms oracle manifold_clutter --out benchmarks/results/clutter_closed_loop.json \\
        --overwrite   # the committed main run

``--splitter`` swaps the stage that splits blobs several objects share (``none``, the default:
left whole; ``keypoints``; ``distance``) in every arm that reads blobs; run once per splitter
with ``--out`` to compare them on the same seeds; ``--support none`` likewise drops the
table-top prior (:mod:`scorbot_gym.perception.support`). ``--regrasps N`` lets the scripted
controller approach again after its fingers close on nothing (default 0), likewise.

``--distractors 0`` runs the same targets in the same poses alone on the table (the target is
placed before its neighbours, with the same draws): what the neighbours cost each arm.
"""

from __future__ import annotations

import argparse
import io
import os
import platform
import sys
import time
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one core per worker: the per-estimate times are 1-core
os.environ.setdefault("MUJOCO_GL", "egl")

ARMS = ("oracle", "manifold_clutter", "largest_blob", "random_blob")
CHUNK = 10  # episodes per task
# (distractors, arm, figure, bound, "min"|"max"): the targets (2 distractors)
TARGETS = (
    (2, "manifold_clutter", "success_rate", 0.90, "min"),
    (2, "manifold_clutter", "wrong_object_rate", 0.02, "max"),
    (2, "manifold_clutter", "target_recognition_accuracy", 0.95, "min"),
    (2, "manifold_clutter", "median_estimate_ms", 40.0, "max"),
)


def _config(
    arm: str,
    distractors: int,
    seed: int,
    episodes: int,
    splitter: str,
    regrasps: int = 0,
    support: str = "table",
):
    from scorbot_gym.evaluation.rollout import CLUTTER_POSE_SOURCES, RolloutConfig

    blobs = arm in CLUTTER_POSE_SOURCES  # the oracle reads no blobs and estimates nothing
    return RolloutConfig(
        pose=arm,
        episodes=episodes,
        seed=seed,
        distractors=distractors,
        splitter=splitter if blobs else "none",
        regrasps=regrasps,
        support=support if blobs else "table",
    )


def run_chunk(
    arm: str,
    distractors: int,
    seed: int,
    episodes: int,
    splitter: str = "none",
    regrasps: int = 0,
    support: str = "table",
) -> list:
    """One chunk of an arm's episodes (a top-level function: it runs in a worker process)."""
    import cv2

    from scorbot_gym.evaluation.rollout import run_rollout

    cv2.setNumThreads(1)
    return run_rollout(_config(arm, distractors, seed, episodes, splitter, regrasps, support))[1]


def arm_summary(
    arm: str,
    distractors: int,
    seed: int,
    results: list,
    splitter: str = "none",
    regrasps: int = 0,
    support: str = "table",
) -> dict:
    from scorbot_gym.evaluation.summary import summarize, wilson_interval

    summary = summarize(results)
    rows = summary.pop("results")
    n = summary["episodes"]
    wrong = summary["failure_causes"].get("wrong_object", 0)
    summary["wrong_object_rate"] = wrong / n
    summary["wrong_object_rate_ci95"] = list(wilson_interval(wrong, n))
    summary["config"] = _config(arm, distractors, seed, n, splitter, regrasps, support).to_dict()
    summary["failed_episodes"] = failed_episodes(rows)
    return summary


def failed_episodes(rows: list[dict]) -> list[str]:
    """One line per failed episode, ``"seed target cause knocked=N picked=R"`` (``picked``:
    the share of estimates taken on the target's blob), to find the episodes behind a figure
    and replay them (``rollout --seed``); successes are the other seeds of the range."""
    out = []
    for r in rows:
        if r["success"]:
            continue
        picked = (r["perception"] or {}).get("target_recognised_rate")
        out.append(
            f"{r['seed']} {r['object_name']} {r['failure_cause']} "
            f"knocked={r['extra'].get('distractors_knocked_over', 0)}"
            + ("" if picked is None else f" picked={picked:.2f}")
        )
    return out


def check_targets(report: dict) -> list[dict]:
    out = []
    for k, arm, figure, bound, kind in TARGETS:
        s = report["runs"].get(str(k), {}).get(arm)
        if s is None:
            continue
        value = s.get(figure, (s.get("perception") or {}).get(figure))
        met = value is not None and (value >= bound if kind == "min" else value <= bound)
        out.append({"distractors": k, "arm": arm, "figure": figure, "bound": bound,
                    "kind": kind, "value": value, "met": bool(met)})  # fmt: skip
    return out


def plot(report: dict, path: Path) -> None:
    import matplotlib

    from pose.fileio import atomic_write_bytes

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = report["runs"]
    ks = sorted(runs, key=int)
    arms = [a for a in ARMS if any(a in runs[k] for k in ks)]
    fig, ax = plt.subplots(figsize=(7, 3.6))
    width = 0.8 / len(arms)
    for j, arm in enumerate(arms):
        for i, k in enumerate(ks):
            s = runs[k].get(arm)
            if s is None:
                continue
            lo, hi = s["success_rate_ci95"]
            x = i + (j - (len(arms) - 1) / 2) * width
            ax.bar(x, s["success_rate"], width, color=f"C{j}", label=arm if i == 0 else None)
            ax.errorbar(x, s["success_rate"], [[s["success_rate"] - lo], [hi - s["success_rate"]]],
                        color="k", lw=1, capsize=2)  # fmt: skip
            ax.text(x, hi + 0.02, f"wrong {s['wrong_object_rate']:.0%}", rotation=90,
                    ha="center", va="bottom", fontsize=7)  # fmt: skip
    ax.axhline(0.9, color="grey", ls="--", lw=1)
    ax.set_xticks(range(len(ks)), [f"target + {k} distractors" for k in ks])
    ax.set_ylabel("grasp success (95 % CI)")
    ax.set_ylim(0, 1.25)
    n = runs[ks[0]][arms[0]]["episodes"]
    ax.set_title(f"cluttered table, {n} seeded episodes per bar, scripted controller", fontsize=9)
    ax.legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=120)
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())


def main(argv: list[str] | None = None) -> int:
    from scorbot_gym.names import SPLITTERS, SUPPORTS  # imports nothing heavy

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=200)
    ap.add_argument("--distractors", type=int, nargs="+", default=[2, 4])
    ap.add_argument("--seed", type=int, default=5000, help="first episode's seed")
    ap.add_argument("--arms", nargs="+", choices=ARMS, default=list(ARMS))
    ap.add_argument("--quick", action="store_true", help="4 episodes, as the config 'quick'")
    ap.add_argument(
        "--out",
        type=Path,
        default=None,
        help="the result file, the main run's PNG beside it (default: runs/clutter_closed_loop-"
        "<time>/clutter_closed_loop.json); an existing file is refused without --overwrite",
    )
    ap.add_argument("--overwrite", action="store_true", help="replace --out if it exists")
    ap.add_argument(
        "--config",
        default=None,
        help="store the run as this named variant of --out (default: the file's main run)",
    )
    ap.add_argument("--jobs", type=int, default=1, help="worker processes (chunks of episodes)")
    ap.add_argument(
        "--splitter",
        choices=SPLITTERS,
        default="none",
        help="how the blob-reading arms split blobs several objects share (default: none)",
    )
    ap.add_argument(
        "--support",
        choices=SUPPORTS,
        default="table",
        help="the blob-reading arms' table-top prior (default: table; none: estimates as the "
        "models answer them)",
    )
    ap.add_argument(
        "--regrasps",
        type=int,
        default=0,
        help="the scripted controller approaches again after closing on nothing, at most this "
        "many times an episode (default 0)",
    )
    args = ap.parse_args(argv)
    from scorbot_gym.experiments.outputs import Outputs

    config = "quick" if args.quick and args.config is None else args.config
    try:  # before any work: an existing file is not replaced unless asked
        out = Outputs("clutter_closed_loop", args.overwrite).path(
            args.out, "clutter_closed_loop.json", companions=[".png"] if config is None else []
        )
    except ValueError as exc:
        ap.error(str(exc))
    if args.episodes < 1 or args.jobs < 1 or any(k < 0 for k in args.distractors):
        ap.error("--episodes and --jobs must be >= 1, --distractors >= 0")
    if args.regrasps < 0:
        ap.error(f"--regrasps must be >= 0, got {args.regrasps}")
    episodes = 4 if args.quick else args.episodes

    from pose.fileio import write_result
    from scorbot_gym.perception.training import default_pose_models

    default_pose_models("top", 320, 240)  # trained once here, not by every worker at once
    options = (args.splitter, args.regrasps, args.support)
    tasks = [
        (arm, k, s, min(CHUNK, args.seed + episodes - s), *options)
        for k in args.distractors
        for arm in args.arms
        for s in range(args.seed, args.seed + episodes, CHUNK)
    ]
    t0 = time.perf_counter()
    if args.jobs > 1:  # spawned: no GL context is inherited
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(args.jobs, mp_context=mp.get_context("spawn")) as pool:
            chunks = list(pool.map(run_chunk, *zip(*tasks, strict=True)))
    else:
        chunks = [run_chunk(*t) for t in tasks]
    wall = time.perf_counter() - t0
    runs: dict[str, dict] = {}
    for k in args.distractors:
        for arm in args.arms:
            results = [r for t, c in zip(tasks, chunks, strict=True) if t[:2] == (arm, k)
                       for r in c]  # fmt: skip
            s = arm_summary(arm, k, args.seed, results, args.splitter, args.regrasps, args.support)
            runs.setdefault(str(k), {})[arm] = s
            p = s["perception"] or {}
            lo, hi = s["success_rate_ci95"]
            print(
                f"{k} distractors {arm:>17}: success {s['success_rate']:6.1%} "
                f"({lo:.1%}-{hi:.1%}) n={s['episodes']}  wrong {s['wrong_object_rate']:.1%}  "
                f"target recog {p.get('target_recognition_accuracy')}  "
                f"ms/estimate {p.get('median_estimate_ms')}  causes {s['failure_causes']}"
                f"  re-grasps (won) {s.get('regrasps')}",
                flush=True,
            )
    report = {
        "episodes": episodes,
        "distractors": args.distractors,
        "seed": args.seed,
        "arms": list(args.arms),
        "splitter": args.splitter,
        "support": args.support,
        "regrasps": args.regrasps,
        "runs": runs,
        "wall_s": wall,
        "jobs": args.jobs,
        "machine": {
            "platform": platform.platform(),
            "cpus": os.cpu_count(),
            "load_average_1min_at_end": os.getloadavg()[0],
        },  # fmt: skip
    }
    report["targets"] = check_targets(report)
    for t in report["targets"]:
        print(f"target {t['figure']} {t['kind']} {t['bound']}: {t['value']} "
              f"({'met' if t['met'] else 'NOT met'})")  # fmt: skip
    write_result(out, report, config)
    if config is None:  # the figure is the main run's
        plot(report, out.with_suffix(".png"))
        print(f"written {out} and {out.with_suffix('.png')}")
    else:
        print(f"written {out} (config {config!r})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
