"""Why the scripted grasp fails among neighbours, and what the neighbour-aware grasp changes.

Runs the ``oracle`` pose source (no perception error: what fails is the approach) on a cluttered
table with two controllers on the same seeds:

- ``blind``: the controller as it was, neighbours hidden, fingers fully open, the nominal
  closing line (``ScriptedGraspPolicy(aperture_margin=None)`` on an observation without
  ``neighbour_points``);
- ``aware``: the default controller, which reads ``neighbour_points`` and chooses the
  equivalent closing line / off-centre grasp with the most clearance and opens to the object's
  width (:mod:`scorbot_gym.policies.grasp_clearance`).

For every episode it records, from the simulator (diagnosis only: the controllers never see
it), the first contact of the hand with a neighbour and the phase it happened in, and sorts the
failures into classes: ``finger_on_neighbour_at_close`` (a finger stood on or against a
neighbour when the gripper closed), ``physics_blew_up`` (a neighbour or the target thrown more
than a metre after the hand met a neighbour), ``target_pushed`` (the target moved more than
1 cm before the fingers closed), ``other``; and for each class whether the hand met a neighbour
during the descent. Writes ``clutter_approach.json`` (into a new ``runs/clutter_approach-<time>/``
unless ``--out`` names a file; ``--config NAME`` stores a variant under ``configs[NAME]``): per
controller the success rate (95 % interval), failure causes, classes, how many episodes met a
neighbour during the descent, and one line per failed episode. The committed record holds
configs only (``100``, ``5100``, ``single_object``), e.g.:

    python benchmarks/clutter_approach.py --episodes 100 --seed 5100 --jobs 2 --config 5100 \\
        --out benchmarks/results/clutter_approach.json --overwrite
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from collections import Counter
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

CONTROLLERS = ("blind", "aware")
CHUNK = 10
HIDDEN = ("neighbour_points", "neighbour_valid")


def run_chunk(controller: str, distractors: int, seed: int, episodes: int) -> list[dict]:
    """Episodes ``seed .. seed + episodes - 1`` of one controller (a worker process)."""
    import numpy as np

    from scorbot_gym.envs.factory import make_env
    from scorbot_gym.policies import ScriptedGraspPolicy

    env = make_env("ScorbotGrasp-v0", pose="oracle", distractors=distractors)
    base = env.unwrapped
    blind = controller == "blind"
    policy = ScriptedGraspPolicy.for_env(env, **({"aperture_margin": None} if blind else {}))

    def seen(obs: dict) -> dict:
        return {k: v for k, v in obs.items() if k not in HIDDEN} if blind else obs

    out = []
    for s in range(seed, seed + episodes):
        obs, info = env.reset(seed=s)
        policy.reset(seen(obs), info)
        target = info["object_name"]
        sim, robot = base.sim, base.robot
        others = [n for n, o in info["objects"].items() if o["role"] == "distractor"]
        start = {n: sim.pose_of(n)[0].copy() for n in [target, *others]}
        first, closed_on, pushed = None, False, 0.0
        while True:
            phase = policy.phase
            obs, _, terminated, truncated, info = env.step(policy.act(seen(obs)))
            for n in others:
                left, right, link = robot.contacts_with(sim.objects[n].geoms)
                if (left or right or link) and first is None:
                    first = phase
                closed_on |= phase == "close" and (left or right)
            if phase in ("approach", "descend"):
                moved = np.linalg.norm(sim.pose_of(target)[0][:2] - start[target][:2])
                pushed = max(pushed, float(moved))
            if terminated or truncated:
                break
        thrown = max(np.linalg.norm(sim.pose_of(n)[0] - p) for n, p in start.items())
        success = bool(info["is_success"])
        kind = None
        if not success:
            if info["failure_cause"] == "unstable" or thrown > 1.0:
                kind = "physics_blew_up"
            elif closed_on:
                kind = "finger_on_neighbour_at_close"
            elif pushed > 0.01:
                kind = "target_pushed"
            else:
                kind = "other"
        out.append(
            {
                "seed": s,
                "target": target,
                "success": success,
                "cause": info["failure_cause"],
                "class": kind,
                "first_neighbour_contact": first,
                "knocked": int(info["distractors_knocked_over"]),
            }
        )
    env.close()
    return out


def summarize(rows: list[dict]) -> dict:
    from scorbot_gym.evaluation.summary import wilson_interval

    n, ok = len(rows), sum(r["success"] for r in rows)
    failed = [r for r in rows if not r["success"]]
    return {
        "episodes": n,
        "success_rate": ok / n,
        "success_rate_ci95": list(wilson_interval(ok, n)),
        "failure_causes": dict(Counter(r["cause"] for r in failed)),
        "failure_classes": dict(Counter(r["class"] for r in failed)),
        "failed_after_a_neighbour_contact_in_descent": sum(
            r["first_neighbour_contact"] == "descend" for r in failed
        ),
        "episodes_with_a_neighbour_contact_before_closing": sum(
            r["first_neighbour_contact"] in ("approach", "descend") for r in rows
        ),
        "distractors_knocked_over": sum(r["knocked"] for r in rows),
        "failed_episodes": [
            f"{r['seed']} {r['target']} {r['cause']} {r['class']} "
            f"first_contact={r['first_neighbour_contact']} knocked={r['knocked']}"
            for r in failed
        ],
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=200)
    ap.add_argument("--distractors", type=int, default=2)
    ap.add_argument("--seed", type=int, default=5000, help="first episode's seed")
    ap.add_argument("--controllers", nargs="+", choices=CONTROLLERS, default=list(CONTROLLERS))
    ap.add_argument("--jobs", type=int, default=1, help="worker processes (chunks of episodes)")
    from scorbot_gym.experiments.outputs import Outputs, add_overwrite_option

    ap.add_argument(
        "--out",
        type=Path,
        default=None,
        help="where to write (default: runs/clutter_approach-<time>/clutter_approach.json; an "
        "existing file is refused without --overwrite)",
    )
    add_overwrite_option(ap)
    ap.add_argument(
        "--config",
        default=None,
        help="store the run as this named variant of --out (default: the file's main run)",
    )
    args = ap.parse_args(argv)
    try:  # before any work: an existing file is not replaced unless asked
        args.out = Outputs("clutter_approach", args.overwrite).path(
            args.out, "clutter_approach.json", "--out", companions=[".png"]
        )
    except ValueError as exc:
        ap.error(str(exc))
    if args.episodes < 1 or args.jobs < 1 or args.distractors < 1:
        ap.error("--episodes, --jobs and --distractors must be >= 1")
    from pose.fileio import write_result

    tasks = [
        (c, args.distractors, s, min(CHUNK, args.seed + args.episodes - s))
        for c in args.controllers
        for s in range(args.seed, args.seed + args.episodes, CHUNK)
    ]
    t0 = time.perf_counter()
    if args.jobs > 1:
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(args.jobs, mp_context=mp.get_context("spawn")) as pool:
            chunks = list(pool.map(run_chunk, *zip(*tasks, strict=True)))
    else:
        chunks = [run_chunk(*t) for t in tasks]
    runs = {}
    for c in args.controllers:
        rows = [r for t, chunk in zip(tasks, chunks, strict=True) if t[0] == c for r in chunk]
        runs[c] = summarize(rows)
        s = runs[c]
        print(f"{c:>6}: success {s['success_rate']:.1%} n={s['episodes']} "
              f"classes {s['failure_classes']}", flush=True)  # fmt: skip
    report = {
        "pose_source": "oracle",
        "distractors": args.distractors,
        "episodes": args.episodes,
        "seed": args.seed,
        "runs": runs,
        "wall_s": time.perf_counter() - t0,
        "jobs": args.jobs,
        "machine": {
            "platform": platform.platform(),
            "cpus": os.cpu_count(),
            "load_average_1min_at_end": os.getloadavg()[0],
        },
    }
    write_result(args.out, report, args.config)
    print(f"written {args.out}" + (f" (config {args.config!r})" if args.config else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
