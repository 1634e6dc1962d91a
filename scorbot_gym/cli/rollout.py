"""``scorbot-gym rollout``: run seeded episodes of a policy and print a summary."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from pose.fileio import atomic_write_bytes, atomic_write_json
from scorbot_gym.envs.factory import make_env
from scorbot_gym.evaluation import format_summary, run_episode, run_episodes, summarize
from scorbot_gym.perception import pose_source_names
from scorbot_gym.policies import RandomPolicy, ScriptedGraspPolicy
from scorbot_gym.policies.sb3 import SHIPPED_POLICY, SB3Policy

POLICIES = ("scripted", "random", "rl")
VIDEO_SUFFIXES = (".mp4", ".gif")


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("rollout", help="run seeded grasping episodes and summarize them")
    p.add_argument("--policy", choices=POLICIES, default="scripted")
    p.add_argument(
        "--pose",
        choices=pose_source_names(),
        default="oracle",
        help="where the policy's object pose comes from",
    )
    p.add_argument(
        "--pose-model",
        type=Path,
        default=None,
        help="model file from `scorbot-gym pose train` (with --pose manifold)",
    )
    p.add_argument(
        "--estimate-every",
        type=int,
        default=1,
        help="estimate the pose every K steps (0: once per episode, at reset)",
    )
    p.add_argument("--episodes", type=int, default=20)
    p.add_argument(
        "--object",
        dest="object_name",
        default=None,
        help="catalogue object (default: a random one per episode)",
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--action-type",
        choices=("joint", "cartesian"),
        default=None,
        help="default: joint; for --policy rl the shipped policy's (cartesian)",
    )
    p.add_argument("--camera", default="overview", help="camera for --video")
    p.add_argument("--video", type=Path, default=None, help="MP4 or GIF of the first episode")
    p.add_argument("--json", type=Path, default=None, help="write the summary as JSON")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=run)


def _pose_kwargs(args: argparse.Namespace) -> dict:
    if args.pose != "manifold":
        return {}
    if args.pose_model is None:
        raise ValueError("--pose manifold needs --pose-model PATH (from `scorbot-gym pose train`)")
    return {"models": args.pose_model}


def _env_id(action_type: str) -> str:
    return "ScorbotGraspCartesian-v0" if action_type == "cartesian" else "ScorbotGrasp-v0"


def _policy(args: argparse.Namespace, env):
    if args.policy == "rl":
        return SB3Policy.load(SHIPPED_POLICY).bind(env)
    if args.policy == "random":
        return RandomPolicy(env.action_space, args.seed)
    return ScriptedGraspPolicy.for_env(env)


def _record_first_episode(args: argparse.Namespace, pose_kwargs: dict) -> None:
    import imageio.v3 as iio

    env = make_env(
        _env_id(args.action_type),
        pose=args.pose,
        pose_kwargs=pose_kwargs,
        estimate_every=args.estimate_every,
        object_name=args.object_name,
        render_mode="rgb_array",
        render_camera=args.camera,
        render_width=480,
        render_height=360,
    )
    frames: list[np.ndarray] = []
    run_episode(
        env, _policy(args, env), args.seed, on_step=lambda o, i: frames.append(env.render())
    )
    env.close()
    fps = env.metadata["render_fps"]
    if args.video.suffix.lower() == ".gif":
        data = iio.imwrite("<bytes>", frames[::2], extension=".gif", duration=2000 / fps, loop=0)
    else:
        data = iio.imwrite("<bytes>", frames, extension=".mp4", fps=fps, macro_block_size=8)
    atomic_write_bytes(args.video, data)
    print(f"video of episode seed={args.seed}: {args.video} ({len(frames)} frames)")


def run(args: argparse.Namespace) -> int:
    if args.episodes < 1:
        raise ValueError(f"--episodes must be >= 1, got {args.episodes}")
    if args.estimate_every < 0:
        raise ValueError(f"--estimate-every must be >= 0, got {args.estimate_every}")
    if args.video and args.video.suffix.lower() not in VIDEO_SUFFIXES:
        raise ValueError(f"--video must end in {' or '.join(VIDEO_SUFFIXES)}, got {args.video}")
    if args.action_type is None:
        rl = args.policy == "rl"
        args.action_type = SB3Policy.load(SHIPPED_POLICY).meta["action_type"] if rl else "joint"
    pose_kwargs = _pose_kwargs(args)
    env = make_env(
        _env_id(args.action_type),
        pose=args.pose,
        pose_kwargs=pose_kwargs,
        estimate_every=args.estimate_every,
        object_name=args.object_name,
    )
    policy = _policy(args, env)
    results = run_episodes(env, policy, args.episodes, args.seed, progress=not args.no_progress)
    env.close()
    summary = summarize(results)
    summary.update(
        policy=args.policy,
        pose_source=args.pose,
        estimate_every=args.estimate_every,
        action_type=args.action_type,
        seed=args.seed,
    )
    print(format_summary(summary))
    if args.json:
        atomic_write_json(args.json, summary)
        print(f"summary written to {args.json}")
    if args.video:
        _record_first_episode(args, pose_kwargs)
    return 0
