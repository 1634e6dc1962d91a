"""Vector-env scaling: env steps/s of 1, 2 and 4 ScorbotGrasp-v0 copies, sync and async, without
images and with one 320x240 image per step, against one plain env.

Run:  python benchmarks/vector_env.py [--repeats 3] [--out PATH.json] [--overwrite] [--config NAME]

By default the run goes to a new ``runs/vector_env-<time>/``; the committed record is rebuilt
with ``--out benchmarks/results/vector_env.json --overwrite`` (a variant of it stored with
``--config NAME``, without a figure, the file's other runs kept).

Every configuration runs in a fresh process (rendering settings are per process), and the
repetitions interleave the configurations so that a change in the machine's load hits all of
them alike; medians are reported. Only the families named pinned, overlapped and independent pin
processes to cores; the others leave placement to the scheduler.
The figures are env steps per wall second over a rollout of random actions, resets included
(the plain env resets itself when an episode ends, the vector envs autoreset), and the CPU time
per env step of the process and its workers, all threads: on a machine shared with other work,
wall-clock ratios depend on the load, the CPU cost of a step much less so. Ratios to the plain
env are taken per repetition, then the median.

Configurations: ``plain`` is ``gym.make`` stepped in a loop; ``sync-N`` is
``gymnasium.make_vec(..., vectorization_mode="sync")``; ``async-N`` is
``gymnasium.make_vec(..., vectorization_mode="async", vector_kwargs={"shared_memory": True})``
(observations, images included, come back through shared memory; the env sends its constant
camera calibration at reset only, so the per-step info stays small); ``async_pinned-N`` is
``gymnasium.vector.AsyncVectorEnv(scorbot_gym.pin_env_fns(...), shared_memory=True)``, the same
with worker ``i`` pinned to core ``i % cores``; ``overlapped-N`` is
``scorbot_gym.OverlappedVectorEnv(scorbot_gym.pin_env_fns(...), shared_memory=True)``: env 0 steps
in the main process (rasterizing in its own thread, ``LP_NUM_THREADS=0``) while pinned workers
step the others; ``independent-N`` is the ceiling no vector env
can beat: N plain envs in N separate processes with no vector env between them, started
together, each pinned to its own core and rasterizing in its own thread like a worker, their
steps/s added up; with ``--ablations``,
``async_cap-N`` also sets ``max_concurrency`` to the usable cores, and ``async_raster_thread-2``
gives each worker's rasterizer one thread of its own. The plain env renders with Mesa's default
threads (one per core), vector-env workers in their calling thread (``scorbot_gym._gl``).
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import platform
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

ENV_ID = "ScorbotGrasp-v0"
COUNTS = (1, 2, 4)
# gymnasium.make_vec settings: sync, async with observations in shared memory, and (with
# --ablations) async with at most one worker stepping per core, for more envs than cores.
FAMILIES: dict[str, dict] = {
    "sync": {"vectorization_mode": "sync"},
    "async": {"vectorization_mode": "async", "vector_kwargs": {"shared_memory": True}},
    "async_cap": {
        "vectorization_mode": "async",
        "vector_kwargs": {"shared_memory": True, "max_concurrency": len(os.sched_getaffinity(0))},
    },
    "async_raster_thread": {
        "vectorization_mode": "async",
        "vector_kwargs": {"shared_memory": True},
    },
    # built by ``build`` from ``scorbot_gym.pin_env_fns``: worker i pinned to core i % cores
    "async_pinned": {"shared_memory": True},
    # built by ``build``: env 0 in the main process, the others in pinned workers
    "overlapped": {"shared_memory": True},
}
# Environment the workers of a family start with: ``async_raster_thread`` (with --ablations)
# gives llvmpipe one rasterizer thread per worker, the previous default, instead of none.
WORKER_ENV: dict[str, dict[str, str]] = {
    "async_raster_thread": {"LP_NUM_THREADS": "1"},
    # the main process steps env 0: it rasterizes in its own thread, like a worker
    "overlapped": {"LP_NUM_THREADS": "0"},
}
SETTINGS = {
    "no_images": {},
    "camera_320x240": {"cameras": ["top"], "image_width": 320, "image_height": 240},
}


def configurations(counts: tuple[int, ...], ablations: bool) -> list[str]:
    names = ["plain"]
    for kind in ("sync", "async", "async_pinned"):
        names += [f"{kind}-{n}" for n in counts]
    names += [f"overlapped-{n}" for n in counts if n > 1]  # env 0 here, the others in workers
    names += [f"independent-{n}" for n in counts if n > 1]
    if ablations:  # the cap only acts with more envs than cores
        names += [f"async_cap-{n}" for n in counts if n > len(os.sched_getaffinity(0))]
        names += [f"async_raster_thread-{n}" for n in counts if n == 2]
    return names


def build(config: str, env_kwargs: dict):
    """The env a configuration names, and its number of sub-environments (0: a plain env)."""
    import gymnasium as gym

    import scorbot_gym  # registers the ids

    if config == "plain":
        return gym.make(ENV_ID, **env_kwargs), 0
    kind, n = config.rsplit("-", 1)
    os.environ.update(WORKER_ENV.get(kind, {}))  # inherited by the workers
    if kind == "async_pinned":
        fns = scorbot_gym.pin_env_fns([functools.partial(gym.make, ENV_ID, **env_kwargs)] * int(n))
        return gym.vector.AsyncVectorEnv(fns, **FAMILIES[kind]), int(n)
    if kind == "overlapped":
        fns = scorbot_gym.pin_env_fns([functools.partial(gym.make, ENV_ID, **env_kwargs)] * int(n))
        return scorbot_gym.OverlappedVectorEnv(fns, **FAMILIES[kind]), int(n)
    return gym.make_vec(ENV_ID, int(n), **FAMILIES[kind], **env_kwargs), int(n)


def time_config(
    config: str,
    setting: str,
    env_steps: int,
    seed: int,
    before_timing: Callable[[], None] | None = None,
) -> dict:
    """Env steps per wall second over ``env_steps`` env steps (after a short warm-up);
    ``before_timing()``, if given, is called between the warm-up and the timed loop."""
    env, n = build(config, {"object_name": "tomato_soup_can", **SETTINGS[setting]})
    calls = max(1, env_steps // max(n, 1))
    env.action_space.seed(seed)
    actions = [env.action_space.sample() for _ in range(calls + 10)]
    env.reset(seed=seed)
    for a in actions[:10]:  # warm-up: GL contexts, caches, worker start-up
        _step(env, a, n)
    if before_timing is not None:
        before_timing()
    pids = [p.pid for p in getattr(env, "processes", [])]
    cpu0, t0 = _cpu_seconds(pids), time.perf_counter()
    for a in actions[10:]:
        _step(env, a, n)
    elapsed, cpu = time.perf_counter() - t0, _cpu_seconds(pids) - cpu0
    env.close()
    steps = calls * max(n, 1)
    return {
        "env_steps_per_second": steps / elapsed,
        "env_steps": steps,
        "cpu_ms_per_env_step": 1e3 * cpu / steps,
    }


def _cpu_seconds(worker_pids: list[int]) -> float:
    """CPU time of this process and its env workers, all threads (Linux ``/proc``): the work a
    step costs, which unlike wall time does not depend on how busy the machine is."""
    total = time.process_time()
    tick = os.sysconf("SC_CLK_TCK")
    for pid in worker_pids:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        total += (int(fields[11]) + int(fields[12])) / tick  # utime, stime
    return total


def info_cost(iterations: int = 2000) -> dict:
    """Per-step cost, in the main process, of an info dict crossing a pipe and being merged by
    ``VectorEnv._add_info``, with and without the camera calibration: what sending it at reset
    only saves (the env used to send it with every step)."""
    import pickle

    import gymnasium as gym

    import scorbot_gym  # noqa: F401  (registers the ids)

    vec = gym.make_vec(
        ENV_ID, 2, "sync", object_name="tomato_soup_can", **SETTINGS["camera_320x240"]
    )
    _, with_cal = vec.reset(seed=0)
    sub = vec.envs[0]
    step_info = sub.step(sub.action_space.sample())[4]
    reset_info = sub.reset(seed=0)[1]
    out = {}
    for name, info in (("with_camera_params", reset_info), ("without", step_info)):
        t0 = time.process_time()
        for _ in range(iterations):
            merged: dict = {}
            for i in range(vec.num_envs):
                merged = gym.vector.VectorEnv._add_info(
                    vec, merged, pickle.loads(pickle.dumps(info)), i
                )
        out[name] = {"us_per_vector_step_2_envs": 1e6 * (time.process_time() - t0) / iterations}
        out[name]["pickled_bytes"] = len(pickle.dumps(info))
    vec.close()
    assert "camera_params" in with_cal and "camera_params" not in step_info
    return out


def _step(env, action, n: int) -> None:
    _, _, terminated, truncated, _ = env.step(action)
    if n == 0 and (terminated or truncated):
        env.reset()


def _median(xs: list[float]) -> float:
    s = sorted(xs)
    k = len(s)
    return s[k // 2] if k % 2 else 0.5 * (s[k // 2 - 1] + s[k // 2])


def run_solo(setting: str, env_steps: int, seed: int, core: int) -> dict:
    """One plain env of an ``independent-N`` run: pinned, warmed up, then it reports ``ready``
    and waits for ``go`` on stdin, so that the N processes time their loops together."""
    os.sched_setaffinity(0, {core})

    def handshake() -> None:
        print("ready", flush=True)
        sys.stdin.readline()

    return time_config("plain", setting, env_steps, seed, before_timing=handshake)


def run_independent(n: int, setting: str, env_steps: int, seed: int) -> dict:
    """``independent-N``: N ``run_solo`` processes on cores ``i % cores``, steps/s summed."""
    cores = sorted(os.sched_getaffinity(0))
    env = {**os.environ, "LP_NUM_THREADS": "0"}  # as in a vector-env worker (scorbot_gym._gl)
    procs = [
        subprocess.Popen(
            [
                sys.executable,
                __file__,
                "--solo",
                setting,
                str(env_steps // n),
                str(seed + i),
                str(cores[i % len(cores)]),
            ],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=env,
        )
        for i in range(n)
    ]
    if not all(p.stdout.readline().strip() == "ready" for p in procs):
        for p in procs:
            p.kill()
        return {"error": "an independent env process failed before its timed loop"}
    for p in procs:
        p.stdin.write("go\n")
        p.stdin.flush()
    outs = [p.communicate() for p in procs]
    if any(p.returncode != 0 for p in procs):
        tail = [e.strip().splitlines()[-1:] for _, e in outs if e.strip()]
        return {"error": f"an independent env process failed: {tail[:1]}"}
    rs = [json.loads(o.strip().splitlines()[-1]) for o, _ in outs]
    return {
        "env_steps_per_second": sum(r["env_steps_per_second"] for r in rs),
        "env_steps": n * (env_steps // n),
        "cpu_ms_per_env_step": _median([r["cpu_ms_per_env_step"] for r in rs]),
    }


def run_child(config: str, setting: str, env_steps: int, seed: int) -> dict:
    kind, _, n = config.rpartition("-")
    if kind == "independent":
        return run_independent(int(n), setting, env_steps, seed)
    cmd = [sys.executable, __file__, "--child", config, setting, str(env_steps), str(seed)]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        tail = proc.stderr.strip().splitlines()[-1:] or ["(no stderr)"]
        return {"error": f"exit {proc.returncode}: {tail[0]}"}
    return json.loads(proc.stdout.strip().splitlines()[-1])


def summarize(runs: dict[str, dict[str, list[dict]]]) -> dict:
    results: dict[str, dict] = {}
    for setting, per_config in runs.items():
        out: dict[str, dict] = {}
        for config, rs in per_config.items():
            good = [r for r in rs if "env_steps_per_second" in r]
            ok = [r["env_steps_per_second"] for r in good]
            out[config] = (
                {
                    "env_steps_per_second_median": _median(ok),
                    "env_steps_per_second_runs": ok,
                    "cpu_ms_per_env_step_median": _median([r["cpu_ms_per_env_step"] for r in good]),
                }
                if ok
                else {"error": rs[-1]["error"]}
            )
        plain = out["plain"].get("env_steps_per_second_median")
        for config, r in out.items():
            if plain and "env_steps_per_second_median" in r:
                # per repetition (next to each other in time, so under about the same load)
                paired = [
                    a["env_steps_per_second"] / b["env_steps_per_second"]
                    for a, b in zip(per_config[config], per_config["plain"], strict=True)
                    if "env_steps_per_second" in a and "env_steps_per_second" in b
                ]
                r["ratio_to_plain"] = _median(paired)
                r["ratio_to_plain_runs"] = paired
                r["cpu_overhead_ms_per_env_step"] = (
                    r["cpu_ms_per_env_step_median"] - out["plain"]["cpu_ms_per_env_step_median"]
                )
        results[setting] = out
    return results


def plot(report: dict, path: Path) -> None:
    """Scaling curves: ratio to one plain env against the number of envs, per setting."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pose.fileio import atomic_write

    settings = list(report["results"])
    fig, axes = plt.subplots(1, len(settings), figsize=(5 * len(settings), 3.4), sharey=True)
    for ax, setting in zip(axes, settings, strict=True):
        res = report["results"][setting]
        styles = {
            "sync": "s--",
            "async": "o-",
            "async_pinned": "v-",
            "async_cap": "^:",
            "async_raster_thread": "D",
            "overlapped": "P-",
            "independent": "k:",
        }
        for kind, style in styles.items():
            pts = [
                (n, res[f"{kind}-{n}"]["ratio_to_plain"])
                for n in report["counts"]
                if "ratio_to_plain" in res.get(f"{kind}-{n}", {})
            ]
            if pts:
                ax.plot(*zip(*pts, strict=True), style, label=kind)
        ax.axhline(1.0, color="#999", lw=0.8)
        ax.set_xticks(report["counts"])
        ax.set_xlabel("number of envs")
        ax.set_title(setting.replace("_", " "))
        ax.legend(fontsize=8)
    axes[0].set_ylabel("env steps/s ÷ one plain env")
    fig.tight_layout()
    atomic_write(path, lambda f: fig.savefig(f, dpi=100, format="png"))
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--child"]:
        config, setting, steps, seed = argv[1:5]
        print(json.dumps(time_config(config, setting, int(steps), int(seed))))
        return 0
    if argv[:1] == ["--solo"]:
        setting, steps, seed, core = argv[1:5]
        print(json.dumps(run_solo(setting, int(steps), int(seed), int(core))))
        return 0
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--steps", type=int, default=3000, help="env steps without images")
    parser.add_argument("--image-steps", type=int, default=300, help="env steps with images")
    parser.add_argument("--counts", type=int, nargs="+", default=list(COUNTS))
    parser.add_argument(
        "--ablations",
        action="store_true",
        help="also async_cap-N for N above the cores and async_raster_thread-2",
    )
    from scorbot_gym.experiments.outputs import Outputs, add_overwrite_option

    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        help="where to write (default: runs/vector_env-<time>/vector_env.json; an existing "
        "file is refused without --overwrite)",
    )
    add_overwrite_option(parser)
    parser.add_argument(
        "--config",
        default=None,
        help="store the run as this named variant of --out (default: the file's main run)",
    )
    args = parser.parse_args(argv)
    try:  # before any work: an existing file is not replaced unless asked
        args.out = Outputs("vector_env", args.overwrite).path(
            args.out, "vector_env.json", "--out", companions=[".png"] if args.config is None else []
        )
    except ValueError as exc:
        parser.error(str(exc))
    if args.repeats < 1 or args.steps < 1 or args.image_steps < 1 or min(args.counts) < 1:
        parser.error("--repeats, --steps, --image-steps and --counts must be >= 1")

    import scorbot_gym
    from pose.fileio import write_result

    configs = configurations(tuple(args.counts), args.ablations)
    steps = {"no_images": args.steps, "camera_320x240": args.image_steps}
    runs = {s: {c: [] for c in configs} for s in SETTINGS}
    load_before, t0 = os.getloadavg(), time.time()
    info = info_cost()
    print(f"info pickling + merging per vector step of 2 envs: {info}", flush=True)
    for rep in range(args.repeats):
        for setting in SETTINGS:
            for config in configs if rep % 2 == 0 else configs[::-1]:
                r = run_child(config, setting, steps[setting], seed=rep)
                runs[setting][config].append(r)
                shown = r.get("error") or f"{r['env_steps_per_second']:8.1f} env steps/s"
                print(f"rep {rep} {setting:>14} {config:>12}: {shown}", flush=True)
    report = {
        "benchmark": "vector_env",
        "env": f"{ENV_ID} (joint actions, tomato_soup_can, random actions)",
        "counts": args.counts,
        "configurations": __doc__.split("Configurations: ")[1].strip(),
        "steps_per_run": steps,
        "repeats": args.repeats,
        "results": summarize(runs),
        "info_cost_main_process": info,
        "load": {
            "loadavg_before": load_before,
            "loadavg_after": os.getloadavg(),
            "wall_seconds": time.time() - t0,
            "note": "the machine is shared; loadavg counts other users' processes too",
        },
        "machine": {
            "platform": platform.platform(),
            "python": sys.version.split()[0],
            "usable_cores": len(os.sched_getaffinity(0)),
            "scorbot_gym": scorbot_gym.__version__,
            "mujoco_gl": os.environ.get("MUJOCO_GL"),
        },
    }
    write_result(args.out, report, args.config)
    if args.config is None:  # the figure is the main run's
        plot(report, args.out.with_suffix(".png"))
    for setting, res in report["results"].items():
        for config, r in res.items():
            shown = r.get("error") or (
                f"{r['env_steps_per_second_median']:8.1f} env steps/s "
                f"({r['ratio_to_plain']:.2f}x plain), {r['cpu_ms_per_env_step_median']:.2f} ms CPU"
            )
            print(f"{setting:>14} {config:>12}: {shown}")
    figure = f" and {args.out.with_suffix('.png')}" if args.config is None else ""
    print(f"written {args.out}{figure}" + (f" (config {args.config!r})" if args.config else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
