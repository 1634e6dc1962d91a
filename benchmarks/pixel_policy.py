"""Pixel policy (imitation on the top camera image, no pose estimator) vs the state policy.

Trains the pixel policy and measures it beside the state imitation policy and the scripted
controller on the same seeds.

The pixel policy (:mod:`scorbot_gym.policies.pixel`) sees an 84 x 84 RGB frame of the top
camera (rendered at 112 x 84, the camera's whole 4:3 field), proprioception, the target class
and its own action history; the shipped state policy (``--policy learned``) sees the oracle
pose instead of the image. Both were trained by BC (DART) + DAgger with the scripted controller
labelling from the oracle pose; neither runs a controller at test time. The paired difference
pixel - state on the same episodes is what the explicit pose estimate buys.

    nice -n 5 python benchmarks/pixel_policy.py [--demos 400] [--dagger-rounds 3]
        [--dagger-episodes 60] [--fit-steps 8000] [--shift 0] [--encoder nature|spatial_softmax]
        [--keypoints 32] [--cameras top[,eye_in_hand]] [--frame-stack 1] [--stall-steps 0]
        [--expert-keeps-close] [--val-demos 0] [--val-episodes 0] [--val-every 0]
        [--episodes 200] [--eval-seed 50000]
        [--jobs 3] [--out DIR] [--json FILE] [--overwrite] [--config NAME] [--skip-training]

The state policy's recipe with the confounds removed (its memory, its two fixes, its
demonstrations; both cameras; the anchors' augmentation, encoder and checkpoint choice):

    python benchmarks/pixel_policy.py --demos 200 --dagger-rounds 4 --dagger-episodes 80 \
        --cameras top,eye_in_hand --frame-stack 3 --stall-steps 50 --expert-keeps-close \
        --shift 4 --encoder spatial_softmax --fit-steps 8000 --val-demos 20 \
        --val-episodes 50 --val-every 4000 --jobs 14 --config matched

Training uses CUDA when available; ``--jobs`` also collects the training episodes in that many
processes (the same episodes for any number). Writes the policy folder (``--out``, not into the
package: its weights are ~4 MB) and ``pixel_policy.json`` (``--json``), by default both into a
new ``runs/pixel_policy-<UTC time>/``; a named path that exists is refused without ``--overwrite``.
The committed record is updated with ``--json benchmarks/results/pixel_policy.json --overwrite``;
``--config NAME`` stores the run as the variant ``configs[NAME]`` of that file (e.g. another
encoder), the file's other runs kept.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

CHUNK = 25  # episodes per evaluation job: the pixel arm renders, so it is split across jobs


def run_chunk(name: str, seed: int, episodes: int) -> list:
    """Episodes ``seed ... seed + episodes - 1`` of one arm (a worker process's job), on the
    env the arm needs (the pixel policy's camera), oracle pose source."""
    import torch

    from scorbot_gym.envs.factory import make_env
    from scorbot_gym.evaluation.compare import resolve_arm
    from scorbot_gym.evaluation.episodes import run_episodes

    torch.set_num_threads(1)  # one-sample predictions: threads only add contention
    arm = resolve_arm(name)
    env = make_env(**{"env_id": "ScorbotGraspCartesian-v0", **arm.env_kwargs}, pose="oracle")
    try:
        return run_episodes(env, arm.build(env, seed), episodes, seed, progress=False)
    finally:
        env.close()


def evaluate(names: dict[str, str], episodes: int, seed: int, jobs: int) -> dict[str, list]:
    """Every arm on seeds ``seed ... seed + episodes - 1`` (episode ``i`` has seed ``seed + i``
    whichever job runs it, so the arms stay paired and the results do not depend on ``jobs``)."""
    tasks = [
        (label, start, min(CHUNK, seed + episodes - start))
        for label in names
        for start in range(seed, seed + episodes, CHUNK)
    ]
    if jobs <= 1:
        done = [run_chunk(names[label], start, n) for label, start, n in tasks]
    else:
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(jobs, mp_context=mp.get_context("spawn")) as pool:
            futures = [pool.submit(run_chunk, names[label], start, n) for label, start, n in tasks]
            done = [f.result() for f in futures]
    out: dict[str, list] = {label: [] for label in names}
    for (label, _, _), results in zip(tasks, done, strict=True):
        out[label] += results
    return out


def render_cost(steps: int = 60) -> dict[str, float]:
    """Median ms per env step (oracle pose wrapper, zero action) without a camera and with the
    top camera rendered at a few sizes: what the image observation costs the data collection."""
    import numpy as np

    from scorbot_gym.envs.factory import make_env

    out = {}
    for label, kw in [
        ("no_camera", {}),
        ("top_84x84", {"cameras": ["top"], "image_width": 84, "image_height": 84}),
        ("top_112x84", {"cameras": ["top"], "image_width": 112, "image_height": 84}),
        ("top_320x240", {"cameras": ["top"], "image_width": 320, "image_height": 240}),
    ]:
        env = make_env("ScorbotGraspCartesian-v0", pose="oracle", include_class=True, **kw)
        try:
            env.reset(seed=0)
            action, times = np.zeros(6, np.float32), []
            for _ in range(steps):
                t = time.perf_counter()
                env.step(action)
                times.append(time.perf_counter() - t)
            out[label] = round(1000 * float(np.median(times)), 3)
        finally:
            env.close()
    return out


def arm_record(name: str, results: list) -> dict:
    """Success with its 95 % Wilson interval, steps, failure causes, per-object success, how
    the policy was trained, and the per-seed outcomes (enough to redo any paired statistic)."""
    import numpy as np

    from scorbot_gym.evaluation.compare import resolve_arm
    from scorbot_gym.evaluation.summary import summarize

    s = summarize(results)
    steps = [r.steps for r in results if r.success]
    return {
        "policy": name,
        "episodes": s["episodes"],
        "successes": s["successes"],
        "success_rate": s["success_rate"],
        "ci95": s["success_rate_ci95"],
        "median_steps_to_success": float(np.median(steps)) if steps else None,
        "failure_causes": s["failure_causes"],
        "per_object": s["per_object"],
        "training": resolve_arm(name).training,
        "episode_success": "".join("1" if r.success else "0" for r in results),
    }


def camera_list(text: str) -> tuple[str, ...]:
    """``--cameras``: comma-separated camera names, each one the env renders."""
    from scorbot_gym.names import FIXED_CAMERAS, MOVING_CAMERAS

    cameras = (*FIXED_CAMERAS, *MOVING_CAMERAS)
    names = tuple(c.strip() for c in text.split(",") if c.strip())
    bad = [c for c in names if c not in cameras]
    if not names or bad or len(set(names)) != len(names):
        raise argparse.ArgumentTypeError(
            f"expected distinct names from {', '.join(cameras)} separated by commas, got {text!r}"
        )
    return names


def main(argv: list[str] | None = None) -> None:
    from scorbot_gym import seeds
    from scorbot_gym.cli._args import non_negative_float, non_negative_int, positive_int
    from scorbot_gym.experiments.outputs import Outputs, add_overwrite_option
    from scorbot_gym.policies.pixel import ENCODERS

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--demos", type=positive_int, default=400)
    p.add_argument("--dart-sigma", type=non_negative_float, default=0.2)
    p.add_argument("--dagger-rounds", type=non_negative_int, default=3)
    p.add_argument("--dagger-episodes", type=positive_int, default=60)
    p.add_argument("--fit-steps", type=positive_int, default=8000)
    p.add_argument("--batch-size", type=positive_int, default=256)
    p.add_argument(
        "--shift",
        type=non_negative_int,
        default=0,
        help="random-shift augmentation, pixels (DrQ; 0: none). At 84 px one pixel is ~1 cm "
        "on the table, so a shift also blurs where the object is",
    )
    p.add_argument("--learning-rate", type=float, default=3e-4)
    p.add_argument("--grayscale", action="store_true", help="1-channel frames instead of RGB")
    p.add_argument(
        "--encoder",
        choices=ENCODERS,
        default="nature",
        help="image encoder: the Nature-DQN stack or spatial-softmax keypoints",
    )
    p.add_argument("--keypoints", type=positive_int, default=32, help="spatial_softmax only")
    p.add_argument(
        "--cameras",
        type=camera_list,
        default=("top",),
        help="comma-separated cameras the policy sees, each with its own encoder "
        "(top, side, overview, eye_in_hand; default: top)",
    )
    p.add_argument(
        "--frame-stack",
        type=positive_int,
        default=1,
        help="frames of each camera the policy sees, the newest last (its memory)",
    )
    p.add_argument(
        "--stall-steps",
        type=non_negative_int,
        default=0,
        help="input how long the TCP has been still, counted up to this many steps (the "
        "state policy's: 50; 0: none)",
    )
    p.add_argument(
        "--val-demos",
        type=non_negative_int,
        default=0,
        help="held-out demonstrations (never fitted) for the label error off the training set",
    )
    p.add_argument(
        "--val-episodes",
        type=non_negative_int,
        default=0,
        help="validation rollouts per checkpoint; the best checkpoint is kept (0: the last)",
    )
    p.add_argument(
        "--val-every",
        type=non_negative_int,
        default=0,
        help="fitting steps between checkpoints (0: only at the end of each fit)",
    )
    p.add_argument(
        "--expert-keeps-close",
        action="store_true",
        help="the DAgger labeller's decision to close stands until the learner closes",
    )
    p.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto")
    p.add_argument("--threads", type=positive_int, default=1, help="torch CPU threads")
    p.add_argument("--episodes", type=positive_int, default=200, help="evaluation episodes")
    p.add_argument("--eval-seed", type=int, default=seeds.TEST.start)
    p.add_argument(
        "--jobs",
        type=positive_int,
        default=1,
        help=f"processes for the training episodes and the evaluation ({CHUNK} episodes each)",
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--out",
        type=Path,
        default=None,
        help="policy folder to write (default: runs/pixel_policy-<time>/policy; with "
        "--skip-training, the folder to evaluate)",
    )
    p.add_argument(
        "--json", type=Path, default=None, help="results (default: beside the policy folder)"
    )
    p.add_argument(
        "--config",
        default=None,
        help="store the run as this named variant of --json (default: the file's main run)",
    )
    p.add_argument("--skip-training", action="store_true", help="evaluate --out as it is")
    add_overwrite_option(p)
    args = p.parse_args(argv)
    outputs = Outputs("pixel_policy", args.overwrite)
    try:  # before any work: a usage error, not a file replaced
        if args.val_every and not args.val_episodes:
            raise ValueError("--val-every needs --val-episodes > 0 (rollouts choose a checkpoint)")
        if args.skip_training:
            if args.out is None or not (Path(args.out) / "policy.json").is_file():
                raise ValueError("--skip-training evaluates --out: name a policy folder")
        else:
            args.out = outputs.path(args.out, "policy", "--out")
        args.json = outputs.path(args.json, "pixel_policy.json", "--json")
    except ValueError as exc:
        p.error(str(exc))

    import torch

    from pose.fileio import write_result
    from scorbot_gym.envs.factory import make_env
    from scorbot_gym.evaluation.summary import newcombe_paired_diff
    from scorbot_gym.policies.imitation import HistorySpec
    from scorbot_gym.policies.loading import SHIPPED
    from scorbot_gym.policies.pixel import DEFAULT_RENDER_SIZE, NetSpec, PixelPolicy
    from scorbot_gym.policies.sb3 import read_policy_json
    from scorbot_gym.rl.pixel import (
        PixelImitationConfig,
        recipe_differences,
        train_pixel_imitation,
    )

    torch.set_num_threads(args.threads)
    step_ms = render_cost()
    print(f"env step, ms (median): {step_ms}", flush=True)
    if not args.skip_training:
        config = PixelImitationConfig(
            demos=args.demos,
            dart_sigma=args.dart_sigma,
            dagger_rounds=args.dagger_rounds,
            dagger_episodes=args.dagger_episodes,
            fit_steps=args.fit_steps,
            batch_size=args.batch_size,
            shift=args.shift,
            learning_rate=args.learning_rate,
            net=NetSpec(
                channels=1 if args.grayscale else 3,
                encoder=args.encoder,
                keypoints=args.keypoints,
                frame_stack=args.frame_stack,
            ),
            cameras=args.cameras,
            history=HistorySpec(stall_steps=args.stall_steps),
            val_demos=args.val_demos,
            val_episodes=args.val_episodes,
            val_every=args.val_every,
            seed=args.seed,
            torch_threads=args.threads,
            jobs=args.jobs,
            expert_keeps_close=args.expert_keeps_close,
            device=args.device,
        )
        width, height = DEFAULT_RENDER_SIZE
        env_kwargs = {
            "env_id": "ScorbotGraspCartesian-v0",
            "pose": "oracle",
            "include_class": True,
            "cameras": list(config.cameras),
            "image_width": width,
            "image_height": height,
        }
        env = make_env(**env_kwargs)
        try:
            policy, _ = train_pixel_imitation(
                env,
                config,
                progress=lambda m: print(m, flush=True),
                on_round=lambda pol, _r: pol.save(args.out),  # a cut run leaves a policy
                env_kwargs=env_kwargs,
            )
        finally:
            env.close()
        policy.save(args.out)
        print(f"policy saved to {args.out}", flush=True)
    policy = PixelPolicy.load(args.out)
    training = policy.meta["training"]

    t0 = time.perf_counter()
    names = {"pixel": str(args.out), "state": "learned", "scripted": "scripted"}
    runs = evaluate(names, args.episodes, args.eval_seed, args.jobs)
    arms = {label: arm_record(names[label], results) for label, results in runs.items()}
    ok = {label: [r.success for r in results] for label, results in runs.items()}
    diffs = {
        "state_minus_pixel": newcombe_paired_diff(ok["state"], ok["pixel"]),
        "pixel_minus_scripted": newcombe_paired_diff(ok["pixel"], ok["scripted"]),
        "state_minus_scripted": newcombe_paired_diff(ok["state"], ok["scripted"]),
    }
    for label, arm in arms.items():
        lo, hi = arm["ci95"]
        print(
            f"{label:>9}: success {arm['success_rate']:.1%} (95% CI {lo:.1%}-{hi:.1%}) "
            f"n={arm['episodes']} failures {arm['failure_causes']}",
            flush=True,
        )
    state_meta = read_policy_json(SHIPPED["learned"] / "policy.json")
    differs = recipe_differences(policy.meta, state_meta)["differs"]
    print("besides the pose, the arms differ in: " + ("; ".join(differs) or "nothing recorded"))
    pose_buys = diffs["state_minus_pixel"]
    print(
        f"the explicit pose estimate buys {pose_buys['diff']:+.1%} (state - pixel, 95% CI "
        f"{pose_buys['ci95'][0]:+.1%}..{pose_buys['ci95'][1]:+.1%}, McNemar p "
        f"{pose_buys['mcnemar_p']:.3g})",
        flush=True,
    )
    size_kb = sum(f.stat().st_size for f in Path(args.out).iterdir()) / 1024
    out = {
        "description": "pixel policy (BC + DART + DAgger on the 84x84 RGB frames of "
        f"{'+'.join(policy.cameras)}, {policy.net_spec.frame_stack} per camera, "
        "no pose estimator) vs the shipped state imitation policy (same recipe, oracle pose) "
        "and the scripted controller; same seeds, whole catalogue, cartesian actions. The "
        "state and scripted arms read the oracle pose; the pixel arm reads no pose entry.",
        "eval_seeds": [args.eval_seed, args.eval_seed + args.episodes - 1],
        "episodes": args.episodes,
        "arms": arms,
        "paired_differences": {
            "method": "Newcombe (1998) method 10 paired-proportion interval; McNemar exact test",
            "state_minus_pixel is": "the success the explicit pose estimate buys, with the "
            "other differences in recipe_vs_state.differs",
            **diffs,
        },
        "pixel_training": {
            k: training.get(k)
            for k in (
                "demonstration_episodes",
                "dagger_episodes",
                "rounds_done",
                "rounds_planned",
                "env_steps",
                "labelled_steps",
                "frames_mb",
                "wall_time_s",
                "fit_time_s",
                "device",
                "rounds",
                "config",
                "augmentation",
                "cameras",
                "frame_stack",
                "validation",
            )
        },
        "pixel_observation": {
            "cameras": list(policy.cameras),
            "frame_stack": policy.net_spec.frame_stack,
            "history": policy.meta["history"],
            "render_size": policy.meta["render_size"],
            "frame_size": policy.net_spec.frame_size,
            "channels": policy.net_spec.channels,
            "encoder": policy.net_spec.encoder,
            "keypoints": policy.net_spec.keypoints,
            "reads": policy.meta["reads"],
        },
        "recipe_vs_state": recipe_differences(policy.meta, state_meta),
        "pixel_policy_size_kb": round(size_kb, 1),
        "env_step_ms_median": step_ms,
        "evaluation_wall_s": round(time.perf_counter() - t0, 1),
        "machine": {
            "cpus": os.cpu_count(),
            "load_average_at_end": [round(x, 2) for x in os.getloadavg()],
            "platform": platform.platform(),
            "cuda": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
        },
        "command": " ".join(["python benchmarks/pixel_policy.py", *(argv or sys.argv[1:])]),
    }
    write_result(args.json, out, args.config)
    print(f"results written to {args.json}" + (f" (config {args.config!r})" if args.config else ""))


if __name__ == "__main__":
    main()
