"""``scorbot-gym rollout``: run seeded closed-loop episodes of a policy and print a summary.

The options' choices come from :mod:`scorbot_gym.names` and the object catalogue; the
episode machinery (simulator, vision stack, learners) is imported by :func:`run` only, so
``--help`` and argument errors take a fraction of a second.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from scorbot_gym.cli._args import (
    add_episode_workers,
    add_name_list,
    non_negative_float,
    non_negative_int,
    positive_int,
    probability,
)
from scorbot_gym.envs.arguments import MAX_TILT_DEG
from scorbot_gym.names import (
    CALIBRATIONS,
    DISTURBANCES,
    FIXED_CAMERAS,
    IDENTITIES,
    MOTIONS,
    MOVING_CAMERAS,
    POLICIES,
    POSE_ALIASES,
    POSE_SOURCES,
    RECOGNIZERS,
    SEGMENTERS,
    SPLITTERS,
    SUPPORTS,
)
from scorbot_gym.objects import CATALOGUE

if TYPE_CHECKING:
    from scorbot_gym.evaluation.rollout import RolloutConfig

CAMERAS = (*FIXED_CAMERAS, *MOVING_CAMERAS)


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "rollout",
        help="run seeded grasping episodes and summarize them",
        description="Run seeded closed-loop grasping episodes: the policy acts on observations "
        "that carry the object pose from the chosen pose source, re-estimated every "
        "--estimate-every steps. Prints success, failure causes and perception figures.",
    )
    p.add_argument(
        "--policy",
        type=_policy,
        default="scripted",
        help=f"who acts: {', '.join(POLICIES)} (scripted: PBVS controller; rl: the shipped "
        "residual; learned: the shipped imitation policy; finetuned: it after RL fine-tuning; "
        "learned_grasp_frame, finetuned_grasp_frame, rl_grasp_frame: learned, finetuned and "
        "rl reading the object's grasp frame, not its class; rl_scratch: SAC from scratch, "
        "no controller and no demonstrations, reading the grasp frame), "
        "or a folder: a policy, or a `scorbot-gym train` run (replays its --checkpoint)",
    )
    p.add_argument(
        "--checkpoint",
        choices=("best", "last"),
        default="best",
        help="for --policy RUN_FOLDER: the policy of the best evaluation (default) or the last",
    )
    p.add_argument(
        "--pose",
        choices=sorted({*POSE_SOURCES, *POSE_ALIASES}),
        default="oracle",
        help="where the object pose in the observation comes from: oracle (ground truth), "
        "noisy/noisy_oracle (ground truth + seeded noise), manifold (the pose-manifold "
        "estimator on camera images; with --distractors it runs manifold_clutter); with "
        "--distractors: manifold_clutter (every blob recognised, the target's estimated), "
        "largest_blob / random_blob (a blob taken without recognition: the baselines); the "
        "image-blind answers, identity given: constant (one pose, position and rotation), "
        "oracle_position (the true position, a constant rotation)",
    )
    p.add_argument(
        "--pose-model",
        type=Path,
        default=None,
        help="model file from `scorbot-gym pose train` for --pose manifold (default: the "
        "default models for the pose camera, trained on first use and cached)",
    )
    p.add_argument(
        "--pose-camera",
        dest="pose_cameras",
        action="append",
        choices=CAMERAS,
        default=None,
        help="camera for --pose manifold, repeatable: the pose comes from the first, recognition "
        "uses all (default: top, plus side when recognising)",
    )
    p.add_argument(
        "--fallback-camera",
        dest="fallback_cameras",
        action="append",
        choices=CAMERAS,
        default=None,
        help="for --pose manifold, repeatable: a camera with default pose models of its own that "
        "estimates where the pose camera's estimate is invalid (e.g. side: the arm hides the "
        "object from the top camera during the grasp)",
    )
    p.add_argument(
        "--motion",
        choices=MOTIONS,
        default=None,
        help="for --pose manifold: where no camera can estimate the pose, 'silhouette' places an "
        "object that moved from its silhouette in any camera (position and heading; default: none)",
    )
    p.add_argument(
        "--segmenter",
        choices=SEGMENTERS,
        default="background",
        help="object mask for --pose manifold: background (subtraction against the empty "
        "workspace, arm removed by its own model) or privileged (the simulator's mask)",
    )
    p.add_argument(
        "--recognizer",
        choices=RECOGNIZERS,
        default=None,
        help="with --recognize: appearance (the default of --pose manifold: the class whose "
        "pose model explains the most keypoints), flr (the FLR classifier on silhouettes) or "
        "flr+appearance (FLR's three best classes, decided by appearance; the default with "
        "--distractors)",
    )
    p.add_argument(
        "--splitter",
        choices=SPLITTERS,
        default="none",
        help="with --distractors: how blobs that several objects share are split before "
        "recognition: none (default: left whole), keypoints (each object's keypoints, assigned "
        "to the model that explains them, seed a watershed) or distance (distance transform)",
    )
    p.add_argument(
        "--support",
        choices=SUPPORTS,
        default=None,
        help="table-top prior of the image-based pose sources: table_memory (the default of "
        "--pose manifold: whether the object rests on the table is decided on the first clear "
        "views and held, and every estimate of a resting one is put on the table), table (the "
        "default with --distractors: each estimate within 5 degrees of a resting pose is put "
        "on the table, along the line of sight) or none (estimates as the models answer them)",
    )
    p.add_argument(
        "--calibration",
        choices=CALIBRATIONS,
        default=None,
        help="with --pose manifold: arm (the default with --segmenter background: each fixed "
        "pose camera re-calibrated at every estimate from the arm's silhouette, against a "
        "calibration error; a correction that moves the object under 3 mm is not applied) or "
        "none (the cameras as calibrated; the default with the other segmenters)",
    )
    p.add_argument(
        "--estimator",
        default="manifold",
        metavar="NAME",
        help="with --pose manifold: manifold (default: the trained models) or a pose.registry "
        "baseline fitted on the same views, e.g. chance (the image-blind answer), with masks, "
        "recognition and prior unchanged",
    )
    p.add_argument(
        "--regrasps",
        type=non_negative_int,
        default=0,
        help="scripted policy: approach again after the fingers close on nothing, at most this "
        "many times an episode (default 0)",
    )
    p.add_argument(
        "--identity",
        choices=IDENTITIES,
        default=None,
        help="--pose manifold only: recognize (default: the object is recognised from the "
        "images, as the main job must) or given (privileged: the estimator is told the true "
        "class, for ablations; the summary says so)",
    )
    p.add_argument(
        "--recognize",
        action="store_true",
        help="--identity recognize (the default for --pose manifold; kept for older commands)",
    )
    p.add_argument(
        "--estimate-every",
        type=non_negative_int,
        default=1,
        help="re-estimate the pose every K steps (0: once per episode, at reset)",
    )
    p.add_argument(
        "--disturb",
        choices=("none", *DISTURBANCES),
        default="none",
        help="move the object during the approach: push (one seeded push and turn) or slide",
    )
    p.add_argument(
        "--pos-sigma-m", type=non_negative_float, default=None, help="noisy: xy noise, m"
    )
    p.add_argument(
        "--yaw-sigma-deg", type=non_negative_float, default=None, help="noisy: heading noise, deg"
    )
    p.add_argument("--dropout", type=probability, default=None, help="noisy: P(estimate lost)")
    p.add_argument(
        "--perturb",
        default=None,
        metavar="K=V,...",
        help="perturb the env, redrawn every episode: lighting, surfaces, camera_pos_m, "
        "camera_rot_deg, blur_sigma, noise_sigma, seed (e.g. surfaces=1.0,noise_sigma=4)",
    )
    p.add_argument(
        "--distractors",
        type=non_negative_int,
        default=0,
        help="other objects on the table beside the target, drawn per episode from --objects "
        "(default: 0, the target alone)",
    )
    p.add_argument(
        "--target",
        default=None,
        metavar="NAME",
        help="the object to grasp in every episode (default: drawn from --objects)",
    )
    p.add_argument(
        "--tilt-deg",
        type=_tilt_deg,
        default=0.0,
        help="prop the target on a stand, tilted this many degrees out of its resting pose "
        f"(0 to {MAX_TILT_DEG:g})",
    )
    p.add_argument("--episodes", type=positive_int, default=20)
    add_episode_workers(p)
    add_name_list(p, "--objects", CATALOGUE, "objects to draw from (default: the catalogue)")
    p.add_argument("--seed", type=int, default=0, help="seed of the first episode")
    p.add_argument(
        "--action-type",
        choices=("joint", "cartesian"),
        default=None,
        help="default: joint; for --policy rl the learned policy's own (cartesian)",
    )
    p.add_argument("--camera", choices=CAMERAS, default="overview", help="camera for --video")
    p.add_argument(
        "--video",
        type=Path,
        default=None,
        help="MP4 or GIF of all the episodes, one after the other (recorded after the run)",
    )
    p.add_argument(
        "--overlay",
        action="store_true",
        help="mark the target and draw the estimated pose's axes on the video",
    )
    p.add_argument(
        "--json", type=Path, default=None, help="write the summary as JSON (checked before the run)"
    )
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=run)


def _tilt_deg(text: str) -> float:
    value = non_negative_float(text)
    if value > MAX_TILT_DEG:
        raise argparse.ArgumentTypeError(f"must be in [0, {MAX_TILT_DEG:g}] degrees, got {text}")
    return value


def _policy(text: str) -> str:
    if text in POLICIES or Path(text).is_dir():
        return text
    raise argparse.ArgumentTypeError(
        f"invalid choice: {text!r} (choose from {', '.join(POLICIES)}, or a policy or "
        "training run folder)"
    )


def check_outputs(args: argparse.Namespace) -> None:
    """``--json`` and ``--video`` writable (one-line errors), before any episode runs."""
    from scorbot_gym.evaluation.video import VIDEO_SUFFIXES
    from scorbot_gym.outputs import check_output_file

    if args.json is not None:
        check_output_file(args.json, "--json", (".json", ".json.gz"))
    if args.video is not None:
        check_output_file(args.video, "--video", VIDEO_SUFFIXES)


def _recognize(args: argparse.Namespace) -> bool:
    """Whether the pose source recognises the object: by default for ``--pose manifold``, so
    the main job reads no ground truth; ``--identity given`` is the privileged opt-out."""
    if args.identity is None:
        return args.recognize or (args.pose == "manifold" and not args.distractors)
    if args.pose != "manifold":
        raise ValueError(
            f"--identity applies to --pose manifold, not {args.pose} (the clutter sources "
            "recognise every blob; the oracle sources read the ground truth)"
        )
    if args.identity == "given" and args.recognize:
        raise ValueError("--recognize and --identity given contradict each other: give one")
    if args.identity == "given" and args.distractors:
        raise ValueError(
            "--identity given does not apply with --distractors: the clutter pipeline is told "
            "the target (the task command) and recognises every blob; drop --identity"
        )
    return args.identity == "recognize"


def config_from_args(args: argparse.Namespace) -> RolloutConfig:
    """Every check happens here, before any episode runs."""
    from scorbot_gym.evaluation.rollout import RolloutConfig
    from scorbot_gym.evaluation.video import VIDEO_SUFFIXES

    if args.video and args.video.suffix.lower() not in VIDEO_SUFFIXES:
        raise ValueError(f"--video must end in {' or '.join(VIDEO_SUFFIXES)}, got {args.video}")
    check_outputs(args)
    if args.overlay and not args.video:
        raise ValueError("--overlay draws on the video: pass --video PATH too")
    if args.pose_model is not None and not args.pose_model.is_file():
        raise FileNotFoundError(f"--pose-model {args.pose_model}: no such file")
    noise = {
        k: v
        for k, v in (
            ("pos_sigma_m", args.pos_sigma_m),
            ("yaw_sigma_deg", args.yaw_sigma_deg),
            ("dropout", args.dropout),
        )
        if v is not None
    }
    return RolloutConfig(
        policy=args.policy,
        pose=args.pose,
        pose_model=str(args.pose_model) if args.pose_model else None,
        pose_cameras=tuple(args.pose_cameras) if args.pose_cameras else None,
        fallback_cameras=tuple(args.fallback_cameras or ()),
        motion=args.motion,
        segmenter=args.segmenter,
        recognizer=args.recognizer,
        recognize=_recognize(args),
        splitter=args.splitter,
        support=args.support,
        calibration=args.calibration,
        estimator=args.estimator,
        estimate_every=args.estimate_every,
        disturbance=None if args.disturb == "none" else args.disturb,
        noise=noise,
        action_type=args.action_type,
        objects=tuple(args.objects) if args.objects else None,
        episodes=args.episodes,
        seed=args.seed,
        perturbation=args.perturb or None,
        checkpoint=args.checkpoint,
        distractors=args.distractors,
        target=args.target,
        tilt_deg=args.tilt_deg,
        regrasps=args.regrasps,
    )


def run(args: argparse.Namespace) -> int:
    from pose.fileio import atomic_write_json
    from scorbot_gym.evaluation import format_summary
    from scorbot_gym.evaluation.rollout import run_rollouts
    from scorbot_gym.evaluation.video import record_episodes

    config = config_from_args(args)
    if config.pose != POSE_ALIASES.get(args.pose, args.pose):
        print(
            f"--pose {args.pose} with --distractors {args.distractors}: the clutter pipeline "
            f"(--pose {config.pose}: blobs split, each recognised, the target's pose estimated)"
        )
    ((summary, _),) = run_rollouts(
        [config], jobs=args.jobs, progress=not args.no_progress, ray=args.ray
    )
    print(format_summary(summary))
    if args.json:
        atomic_write_json(args.json, summary)
        print(f"summary written to {args.json}")
    if args.video:
        env = config.make_env(
            render_mode="rgb_array", render_camera=args.camera, render_width=480, render_height=360
        )
        try:
            seeds = range(config.seed, config.seed + config.episodes)
            _, n = record_episodes(env, config.make_policy(env), seeds, args.video, args.overlay)
        finally:
            env.close()
        print(f"video of episodes seed={seeds[0]}..{seeds[-1]}: {args.video} ({n} frames)")
    return 0
