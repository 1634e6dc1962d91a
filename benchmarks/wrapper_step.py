"""What ``PoseEstimateObservation`` with the oracle source costs per step, next to the bare env,
without images and with the ``top`` camera's 320x240 RGB in the observation; and, with
``--train-steps``, SAC's training throughput on the oracle-wrapped env (1 and 2 envs).

Run:  python benchmarks/wrapper_step.py [--repeats 7] [--train-steps 3000] [--out PATH.json]
      [--overwrite]

By default the report goes to a new ``runs/wrapper_step-<time>/wrapper_step.json``; the
committed record is rebuilt with ``--out benchmarks/results/wrapper_step.json --overwrite`` (an
existing ``--out`` is refused without ``--overwrite``).

The step timing is ``benchmarks/env_step.py``'s: the loop of ``benchmarks/peers/time_env.py``
(uniform random actions, resets untimed), one fresh process per env, setting and repetition,
all pinned to one core, the two envs interleaved (bare, wrapped, then wrapped, bare, ...); the
ratio of CPU time per step is taken within each repetition, then its median and range
reported. The wrapped env scores its estimate
against the truth at every step (``info["perception"]``: rotation error over the object's
symmetries, ADD-S), as in training and evaluation. ``profile`` breaks the wrapped step into
stages (``time_env.py --profile``).

Training throughput (``--train-steps`` > 0): SAC as ``scorbot-gym train`` builds it
(:func:`scorbot_gym.rl.training.build_model`: oracle pose, Cartesian actions, whole catalogue),
timed over ``learn`` only (envs built before), first the steps before ``learning_starts``
(collection only), then the rest (one gradient update per vector-env step, SB3's default);
both cores, not pinned: a subprocess vector env needs one per env. Every object's scene is
compiled before timing (a process compiles each once, ~0.2 s, then keeps it).
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import env_step  # noqa: E402  (the timing harness this benchmark shares)

BARE = "ScorbotGrasp-v0"
WRAPPED = "ScorbotGrasp-v0/pose-oracle"


def time_pair(repeats: int, steps: dict[str, int]) -> dict:
    """Bare and wrapped env, interleaved in each repetition, without an image and with the
    ``top`` camera's 320x240 RGB in the observation (``env_step.SETTINGS``); per setting each
    env's medians and the wrapped step's CPU time over the bare one's, paired per repetition."""
    python = Path(sys.executable)
    out: dict = {}
    for setting, image in env_step.SETTINGS.items():
        runs: dict[str, list[dict]] = {BARE: [], WRAPPED: []}
        for rep in range(repeats):
            for env in (BARE, WRAPPED) if rep % 2 == 0 else (WRAPPED, BARE):
                r = env_step.time_once(python, env, image, steps[setting], seed=rep)
                runs[env].append(r)
                rate = r.get("steps_per_cpu_second")
                shown = f"{rate:8.1f} steps/CPU s" if rate else r["error"]
                print(f"rep {rep} {setting:>14} {env:>28}: {shown}", flush=True)
        per_env: dict = {}
        for env, rs in runs.items():
            ok = [r for r in rs if "steps_per_second" in r]
            if not ok:
                raise SystemExit(f"{env} ({setting}): every run failed ({rs[-1]['error']})")
            cpu = env_step._median([r["steps_per_cpu_second"] for r in ok])
            per_env[env] = {
                "steps_per_cpu_second_median": cpu,
                "cpu_us_per_step_median": 1e6 / cpu,
                "steps_per_cpu_second_runs": [r["steps_per_cpu_second"] for r in ok],
                "steps_per_second_median": env_step._median([r["steps_per_second"] for r in ok]),
                "steps_per_run": steps[setting],
                "failed_runs": len(rs) - len(ok),
                "note": ok[0]["note"],
                "render_settings": ok[0]["render_settings"],
            }
        # wrapped step time over bare step time = bare steps per CPU s over wrapped ones
        paired = env_step.paired_ratio(runs[BARE], runs[WRAPPED])
        per_env["wrapped_over_bare"] = {
            "cpu_time_ratio_median": paired["cpu_ratio_median"],
            "cpu_time_ratio_min": paired["cpu_ratio_min"],
            "cpu_time_ratio_max": paired["cpu_ratio_max"],
            "cpu_time_ratio_runs": paired["cpu_ratio_runs"],
            "wall_time_ratio_median": paired["wall_ratio_median"],
            "pairs": paired["pairs"],
        }
        out[setting] = per_env
    return out


def profile_wrapped(repeats: int, steps: dict[str, int]) -> dict:
    """The wrapped step's stages (``time_env.py --profile``), per setting: medians over
    ``repeats`` fresh processes."""
    python = Path(sys.executable)
    out = {}
    for setting, image in env_step.SETTINGS.items():
        runs = []
        for rep in range(repeats):
            r = env_step.time_once(python, WRAPPED, image, steps[setting], rep, profile=True)
            if "error" not in r:
                runs.append(r)
        if not runs:
            continue
        keys = runs[0]["parts_us"]
        out[setting] = {
            "step_us_median": env_step._median([r["step_us"] for r in runs]),
            "parts_us_median": {
                k: env_step._median([r["parts_us"][k] for r in runs]) for k in keys
            },
            "runs": len(runs),
        }
    return out


def train_throughput(n_envs: int, steps: int, learning_starts: int, seed: int) -> dict:
    """Env steps per second of SAC's ``learn`` on the oracle-wrapped env with ``n_envs`` envs."""
    from scorbot_gym.objects import CATALOGUE
    from scorbot_gym.rl.training import TrainConfig, build_model, make_vec_env

    config = TrainConfig(
        algo="sac",
        pose="oracle",
        timesteps=steps,
        n_envs=n_envs,
        seed=seed,
        hyperparams={"learning_starts": learning_starts},
        progress_bar=False,
        tensorboard=False,
    ).validate()
    from scorbot_gym.rl import training

    training._limit_threads(config.torch_threads)
    venv = make_vec_env(config)
    try:
        for name in config.objects or list(CATALOGUE):  # compile every scene before timing
            venv.env_method("reset", options={"object_name": name})
        model = build_model(config, venv, None)
        t0 = time.perf_counter()
        model.learn(learning_starts)
        collect_s = time.perf_counter() - t0
        collected = model.num_timesteps
        t1 = time.perf_counter()
        model.learn(steps - collected, reset_num_timesteps=False)
        train_s = time.perf_counter() - t1
        updates = int(model._n_updates)
        trained_steps = model.num_timesteps - collected
    finally:
        venv.close()
    return {
        "n_envs": n_envs,
        "env_steps": int(model.num_timesteps),
        "collection_env_steps_per_second": collected / collect_s,
        "training_env_steps_per_second": trained_steps / train_s,
        "overall_env_steps_per_second": model.num_timesteps / (collect_s + train_s),
        "gradient_updates": updates,
        "gradient_updates_per_env_step": updates / max(1, trained_steps),
        "wall_seconds": collect_s + train_s,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=2000, help="timed steps without images")
    parser.add_argument("--image-steps", type=int, default=200, help="timed steps with images")
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--cpu", type=int, default=0, help="core to pin the step timing to")
    parser.add_argument(
        "--train-steps", type=int, default=0, help="SAC env steps per throughput run (0: skip)"
    )
    parser.add_argument("--learning-starts", type=int, default=1000)
    from scorbot_gym.experiments.outputs import Outputs, add_overwrite_option

    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        help="where to write (default: runs/wrapper_step-<time>/wrapper_step.json; an existing "
        "file is refused without --overwrite)",
    )
    add_overwrite_option(parser)
    args = parser.parse_args(argv)
    try:  # before any work: an existing file is not replaced unless asked
        args.out = Outputs("wrapper_step", args.overwrite).path(
            args.out, "wrapper_step.json", "--out", companions=[".png"]
        )
    except ValueError as exc:
        parser.error(str(exc))
    if args.steps < 1 or args.image_steps < 1 or args.repeats < 1 or args.train_steps < 0:
        parser.error("--steps, --image-steps and --repeats must be >= 1, --train-steps >= 0")
    if args.train_steps and not 0 < args.learning_starts < args.train_steps:
        parser.error("--learning-starts must be in (0, --train-steps)")

    import scorbot_gym
    from pose.fileio import atomic_write_json

    load_before = os.getloadavg()
    cores = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else None
    if cores is not None:
        os.sched_setaffinity(0, {args.cpu})  # inherited by the timing subprocesses
    t0 = time.time()
    steps = {"no_images": args.steps, "camera_320x240": args.image_steps}
    step = time_pair(args.repeats, steps)
    prof = profile_wrapped(min(3, args.repeats), steps)
    if cores is not None:
        os.sched_setaffinity(0, cores)  # training uses every core it was given
    training = []
    if args.train_steps:
        os.environ.setdefault("MUJOCO_GL", "egl")
        for n in (1, 2):
            r = train_throughput(n, args.train_steps, args.learning_starts, seed=0)
            training.append(r)
            print(
                f"SAC, {n} env(s): {r['overall_env_steps_per_second']:.0f} env steps/s "
                f"({r['collection_env_steps_per_second']:.0f} collecting, "
                f"{r['training_env_steps_per_second']:.0f} with updates; "
                f"{r['gradient_updates_per_env_step']:.2f} updates per env step)",
                flush=True,
            )
    report = {
        "benchmark": "wrapper_step",
        "step": step,
        "profile_wrapped": prof,
        "timing": {
            "steps_per_run": steps,
            "ratio": "wrapped over bare CPU time per step (time.process_time of the timing "
            "process), run against run of the same repetition; median and range",
            "repeats": args.repeats,
            "pinned_cpu": args.cpu,
            "loop": "benchmarks/peers/time_env.py, one fresh process per env and repetition",
        },
        "training_throughput": training,
        "training_setup": "SAC (build_model of scorbot_gym.rl.training), oracle pose, Cartesian "
        "actions, whole catalogue; DummyVecEnv for 1 env, SubprocVecEnv for 2",
        "load": {
            "loadavg_before": load_before,
            "loadavg_after": os.getloadavg(),
            "wall_seconds": time.time() - t0,
            "note": "the machine is shared; loadavg counts other users' processes too",
        },
        "machine": {
            "platform": platform.platform(),
            "python": sys.version.split()[0],
            "cpu_count": os.cpu_count(),
            "scorbot_gym": scorbot_gym.__version__,
        },
    }
    atomic_write_json(args.out, report)
    for setting, per_env in step.items():
        r = per_env["wrapped_over_bare"]
        print(
            f"{setting}: bare {per_env[BARE]['cpu_us_per_step_median']:.0f} CPU us/step, "
            f"oracle-wrapped {per_env[WRAPPED]['cpu_us_per_step_median']:.0f}: "
            f"{r['cpu_time_ratio_median']:.2f}x ({r['cpu_time_ratio_min']:.2f}-"
            f"{r['cpu_time_ratio_max']:.2f}, {r['pairs']} pairs)"
        )
    print(f"written {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
