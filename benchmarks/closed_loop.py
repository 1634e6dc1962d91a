"""Closed-loop grasping with the pose estimator in the loop: the targets of the
perception-in-the-loop issue, measured in one run.

Arms (every arm runs the same seeded episodes over the whole catalogue):

- ``oracle``: ground-truth pose, re-read every step (the ceiling);
- ``manifold``: the pose-manifold estimator on the top camera, re-estimated every step, with the
  rollout defaults for masks and identity (background subtraction; FLR shortlist + appearance
  recognition) and the per-estimate table-top prior (``support="table"``, the default until
  2026-11-27: the arms below were measured with it): no privileged input. Variants swap one
  component: no table-top prior (estimates as the models answer them), the prior decided once
  an episode on clear views and held (``support="table_memory"``, the rollout default since
  2026-11-27; alone and with appearance recognition, and that with each fixed pose camera
  re-calibrated from the arm's silhouette, ``calibration="arm"``), the
  resting-view models in place of the default ones, the resting-view models as a resting
  hypothesis (their estimate wherever the default models answer a near-resting pose), FLR
  alone or appearance alone as the recogniser, the ``side`` camera's own pose models where the
  top view is hidden. Each arm's failed episodes are kept by seed (``failed``), so two arms of
  one run pair episode by episode;
- the blind arms, each named for what it ignores, beside the estimator: ``rotation-blind (image
  position, constant rotation)``, the ``manifold`` arm with the trained models swapped for a
  constant rotation fitted on their views (``RolloutConfig.estimator="chance"``), masks,
  recognition and prior unchanged: the position (and the identity) still from the images;
  ``rotation-blind (true position, constant rotation)``, the ``oracle_position`` source (the
  true position, one rotation: heading 0 on the first resting face); ``image-blind (constant
  pose, identity given)``, the ``constant`` source (that rotation at the centre of the
  placement region, whatever the cameras see: the floor);
- ``push``: a seeded push + turn of the object during the approach, for the servoing controller
  (re-estimating every step) and the estimate-once controller, with oracle and manifold poses;
  ``silhouette motion`` arms add ``motion="silhouette"`` to the side-fallback source;
- ``eye-in-hand``: the pose from the camera on the hand (640 x 480, its models trained from the
  arm's home pose), segmented in its depth image (no reference frame for a moving camera),
  the object's identity given;
- a robustness curve: success vs ``noisy_oracle`` heading noise (0-30 deg) and position noise
  (0-3 cm), re-estimated every step.

``--jobs N`` runs the arms' episodes in chunks of seeds over N processes
(:func:`scorbot_gym.evaluation.rollout.run_rollouts`: every episode depends on its seed alone, so
the figures do not depend on N); the in-loop timing runs afterwards, alone. ``--arms`` runs a
subset (``robustness``: the noise curves; the timing goes with ``manifold``), and ``--merge
PART.json ...`` joins the reports of such runs into the one a whole run writes, so a long batch
can be split over several commands. Writes ``closed_loop.json``, by default into a new
``runs/closed_loop-<time>/`` (``--out`` names the file, an existing one only with
``--overwrite``; the committed record is ``--out benchmarks/results/closed_loop.json
--overwrite``) (the default run at its top level; ``--config NAME`` stores a variant, e.g.
another model set, under ``configs[NAME]`` and leaves the rest of the file as it was) and, for
the default run, ``closed_loop.png``.

``--perturbations "none;lighting=0.5;..."`` runs instead the ``manifold`` arm once per env
perturbation (``scorbot_gym.data.perturbations``, redrawn every episode; the pose models are the
unperturbed ones): the perturbation axes in the loop, stored as the config ``perturbations`` of
``closed_loop.json`` (unless ``--config`` names another); ``--perturbation-support``,
``--perturbation-recognizer`` and ``--perturbation-calibration`` choose that arm's components.

    python benchmarks/closed_loop.py [--episodes 220] [--curve-episodes 44] [--jobs 16] [--quick]
    python benchmarks/closed_loop.py --arms "oracle;manifold;robustness" --out part1.json
    python benchmarks/closed_loop.py --merge part1.json part2.json \\
        --out benchmarks/results/closed_loop.json --overwrite
    python benchmarks/closed_loop.py --perturbations "none;calibration=1" --jobs 16 \\
        --out benchmarks/results/closed_loop.json --overwrite   # config 'perturbations'
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from dataclasses import replace
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one core per worker (inherited): --jobs N uses N cores
os.environ.setdefault("MUJOCO_GL", "egl")

#: the ``--arms`` name of the noise curves (the ``robustness`` section of the report)
ROBUSTNESS = "robustness"
#: the ``manifold`` arm with its models swapped for a constant rotation (``estimator="chance"``)
ROTATION_BLIND_ARM = "rotation-blind (image position, constant rotation)"
#: the ``oracle_position`` source: the true position, a constant rotation
TRUE_POSITION_ARM = "rotation-blind (true position, constant rotation)"
#: the ``constant`` source: one pose, whatever the cameras see
IMAGE_BLIND_ARM = "image-blind (constant pose, identity given)"
#: the ``manifold`` arm with the resting-view models as its resting hypothesis
RESTING_HYPOTHESIS_ARM = "manifold, resting-view hypothesis"
#: the ``manifold`` arm, its table-top prior decided once an episode (``"table_memory"``)
TABLE_MEMORY_ARM = "manifold, table prior held per episode"
#: that arm with appearance recognition over every class (no FLR shortlist)
TABLE_MEMORY_APPEARANCE_ARM = "manifold, table prior held per episode, appearance recognition"
#: that arm with each fixed pose camera re-calibrated from the arm's silhouette
ARM_CALIBRATION_ARM = f"{TABLE_MEMORY_APPEARANCE_ARM}, arm calibration"
#: the ``manifold`` arm with the resting-view models (the default before the tilted views)
RESTING_MODELS_ARM = "manifold, resting-view models"
#: the placeholder of that arm's ``pose_model``, the cache file once the run starts
RESTING_MODELS = "<the resting-view default models>"
#: the labels earlier reports gave arms, and the label each has now (``--merge`` reads old files)
RENAMED_ARMS = {"chance (image-blind estimator)": ROTATION_BLIND_ARM}
#: the config its ``--perturbations`` runs are stored under by default
PERTURBATIONS = "perturbations"
YAW_SIGMAS = (0.0, 5.0, 10.0, 20.0, 30.0)
POS_SIGMAS_CM = (0.0, 0.5, 1.0, 2.0, 3.0)
# at 320 x 240 the small objects are too few pixels from the hand camera's home pose to train
EYE_IN_HAND_SIZE = (640, 480)


def _run_arms(runs: list, jobs: int, progress: bool) -> dict[str, dict]:
    """Run ``(label, config)`` pairs, their episodes in chunks over ``jobs`` processes
    (:func:`~scorbot_gym.evaluation.rollout.run_rollouts`: the same episodes for any ``jobs``);
    per label the summary without its per-episode rows, ``wall_s`` its one-core seconds."""
    from scorbot_gym.evaluation.rollout import run_rollouts

    done = run_rollouts([config for _, config in runs], jobs=jobs, progress=progress)
    out = {}
    for (label, _), (summary, results) in zip(runs, done, strict=True):
        summary.pop("results", None)
        summary["label"] = label
        # the failed episodes by seed (the others succeeded): arms of one run pair episode by
        # episode, for McNemar's test
        summary["failed"] = {
            str(r.seed): [r.object_name, r.failure_cause or "failed"]
            for r in results
            if not r.success
        }
        lo, hi = summary["success_rate_ci95"]
        p = summary.get("perception") or {}
        print(
            f"{label:>28}: success {summary['success_rate']:6.1%} (95% CI {lo:.1%}-{hi:.1%}) "
            f"n={summary['episodes']}  valid {p.get('valid_rate', 0):.1%}  "
            f"recog {p.get('recognition_accuracy')}  failures {summary['failure_causes']}",
            flush=True,
        )
        out[label] = summary
    return out


def _plot(report: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    arms = report["arms"]
    labels = list(arms)
    rates = [arms[k]["success_rate"] for k in labels]
    err = [
        [r - arms[k]["success_rate_ci95"][0] for k, r in zip(labels, rates, strict=True)],
        [arms[k]["success_rate_ci95"][1] - r for k, r in zip(labels, rates, strict=True)],
    ]
    axes[0].barh(labels, rates, xerr=err, color="tab:blue", alpha=0.8)
    axes[0].set_xlim(0, 1.02)
    axes[0].set_xlabel("grasp success (95% CI)")
    axes[0].set_title("closed loop, scripted PBVS")
    for ax, key, unit in ((axes[1], "yaw", "deg"), (axes[2], "pos", "cm")):
        curve = report["robustness"][key]
        xs = [c["sigma"] for c in curve]
        ys = [c["success_rate"] for c in curve]
        lo = [c["success_rate_ci95"][0] for c in curve]
        hi = [c["success_rate_ci95"][1] for c in curve]
        ax.plot(xs, ys, "o-", color="tab:red")
        ax.fill_between(xs, lo, hi, color="tab:red", alpha=0.2)
        ax.set_ylim(0, 1.02)
        ax.set_xlabel(f"noisy_oracle {key} sigma ({unit})")
        ax.set_ylabel("grasp success")
        ax.set_title(f"robustness to {key} noise\n(re-estimated every step)")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def _out(parser: argparse.ArgumentParser, args: argparse.Namespace, name: str) -> Path:
    """``--out``, or ``name`` in a new runs/ folder; an existing file needs --overwrite."""
    from scorbot_gym.experiments.outputs import Outputs

    try:
        drawn = [".png"] if args.config is None else []  # the figure is the main run's
        return Outputs("closed_loop", args.overwrite).path(args.out, name, companions=drawn)
    except ValueError as exc:
        parser.error(str(exc))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--episodes", type=int, default=220, help="episodes per main arm")
    parser.add_argument("--push-episodes", type=int, default=110, help="per disturbed arm")
    parser.add_argument("--curve-episodes", type=int, default=44, help="per robustness point")
    parser.add_argument(
        "--eye-in-hand-episodes", type=int, default=44, help="for the eye-in-hand arm"
    )
    parser.add_argument("--segmenter", default="background", help="mask source for manifold")
    parser.add_argument("--no-recognize", action="store_true", help="give the identity instead")
    parser.add_argument("--seed", type=int, default=1000)
    parser.add_argument("--quick", action="store_true", help="a few episodes, to check it runs")
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        help="the result file (default: runs/closed_loop-<time>/closed_loop.json); an existing "
        "file is refused without --overwrite",
    )
    parser.add_argument(
        "--overwrite", action="store_true", help="replace --out (and its PNG) if it exists"
    )
    parser.add_argument(
        "--config",
        default=None,
        help="store the run as this named variant of --out (default: the file's main run; "
        f"{PERTURBATIONS!r} with --perturbations)",
    )
    parser.add_argument("--progress", action="store_true")
    parser.add_argument(
        "--jobs", type=int, default=1, help="processes, each running chunks of an arm's episodes"
    )
    parser.add_argument(
        "--arms",
        default=None,
        help=f'";"-separated arm labels to run, "{ROBUSTNESS}" for the noise curves '
        "(default: every arm and the curves)",
    )
    parser.add_argument(
        "--perturbations",
        default=None,
        help='";"-separated env perturbations ("none": unperturbed), the manifold arm under each',
    )
    parser.add_argument(
        "--perturbation-support",
        choices=("table", "table_memory", "none"),
        default="table",
        help="the table-top prior of the --perturbations arms (default: table, the per-estimate "
        "prior the committed config was measured with; table_memory is the rollout default)",
    )
    parser.add_argument(
        "--perturbation-recognizer",
        choices=("flr+appearance", "appearance", "flr"),
        default="flr+appearance",
        help="the recogniser of the --perturbations arms (default: flr+appearance, as the "
        "committed config was measured; appearance is the rollout default)",
    )
    parser.add_argument(
        "--perturbation-calibration",
        choices=("none", "arm"),
        default="none",
        help="the camera calibration of the --perturbations arms (default: none, the cameras "
        "as calibrated, as the committed configs were measured; arm: re-calibrated from the "
        "arm's silhouette)",
    )
    parser.add_argument(
        "--merge",
        nargs="+",
        type=Path,
        default=None,
        metavar="PART",
        help="join the JSONs of runs of disjoint --arms (or --perturbations) into --out",
    )
    args = parser.parse_args(argv)
    if args.jobs < 1:
        parser.error(f"--jobs must be >= 1, got {args.jobs}")
    if args.merge is not None:
        return _merge(parser, args)
    labels = _perturbation_labels(parser, args)
    if labels and args.config is None:
        args.config = PERTURBATIONS
    args.out = _out(parser, args, "closed_loop.json")
    if args.quick:
        args.episodes, args.push_episodes, args.curve_episodes = 6, 6, 3
        args.eye_in_hand_episodes = 2
    only = None if args.arms is None else [a.strip() for a in args.arms.split(";")]
    if only is not None:
        unknown = [a for a in only if a not in (*_arm_configs(args), ROBUSTNESS)]
        if unknown:
            parser.error(f"unknown arms {unknown}; valid: {[*_arm_configs(args), ROBUSTNESS]}")

    import cv2

    from pose.fileio import write_result
    from scorbot_gym.evaluation.rollout import RolloutConfig
    from scorbot_gym.perception.baseline_models import baseline_models_like
    from scorbot_gym.perception.training import default_pose_models

    cv2.setNumThreads(1)  # the estimator's figures are for one core
    t0 = time.perf_counter()
    arms = {k: v for k, v in _arm_configs(args).items() if only is None or k in only}
    # trained here, once, not by every worker at the same time (none for arms without images)
    if labels or any(c.pose == "manifold" for c in arms.values()):
        default_pose_models("top", 320, 240, progress=args.progress)
    if labels:
        return _perturbation_arms(args, labels, time.perf_counter() - t0)
    arms = {  # the resting-view models trained (once) and named by their cache file
        k: replace(c, pose_model=_resting_models_file()) if c.pose_model == RESTING_MODELS else c
        for k, c in arms.items()
    }
    if any(c.resting_hypothesis for c in arms.values()):
        from scorbot_gym.perception.training import RESTING_TRAINING

        default_pose_models("top", 320, 240, progress=args.progress, training=RESTING_TRAINING)
    if any(c.fallback_cameras for c in arms.values()):
        default_pose_models("side", 320, 240, progress=args.progress)
    if any(c.pose_cameras[0] == "eye_in_hand" for c in arms.values()):
        default_pose_models("eye_in_hand", *EYE_IN_HAND_SIZE, progress=args.progress)
    for config in arms.values():  # a baseline's set is fitted here, once, and cached
        if config.estimator != "manifold":
            models = default_pose_models(config.pose_cameras[0], *config.pose_size)
            baseline_models_like(config.estimator, models, args.jobs, args.progress)
    train_s = time.perf_counter() - t0

    n, seed = args.episodes, args.seed
    report: dict = {
        "benchmark": "closed_loop",
        "episodes_per_arm": n,
        "episodes_per_disturbed_arm": args.push_episodes,
        "seed": seed,
        "pose_model_ready_s": train_s,
        "arms": {},
        "robustness": {"yaw": [], "pos": []},
    }
    curves = _curves() if only is None or ROBUSTNESS in only else []
    runs = list(arms.items()) + [
        (label, RolloutConfig(pose="noisy", noise=noise, episodes=args.curve_episodes, seed=seed))
        for _, _, label, noise in curves
    ]
    done = _run_arms(runs, args.jobs, args.progress)
    for label in arms:
        report["arms"][label] = done[label]
    for key, sigma, label, _ in curves:
        report["robustness"][key].append({"sigma": sigma, **_curve_point(done[label])})
    write_result(args.out, report, args.config)
    if "manifold" in arms:  # alone, after the arms: a timing shares the machine with nothing
        timing = _loop_timing(arms["manifold"], max(2, n // 20))
        report["loop_timing_320x240_one_thread"] = timing
        print(f"perception in the loop, 320x240, one thread: {timing}", flush=True)
    report["machine"] = _machine(args.jobs)
    write_result(args.out, report, args.config)
    # the figure is the main run's; its right panels are the noise curves
    if args.config is None and report["robustness"]["yaw"]:
        _plot(report, args.out.with_suffix(".png"))
        print(f"written {args.out} and {args.out.with_suffix('.png')}")
    else:
        print(f"written {args.out}" + (f" (config {args.config!r})" if args.config else ""))
    return 0


def _arm_configs(args) -> dict:
    """The arms of the main run, by label (in the report's order)."""
    from scorbot_gym.evaluation.rollout import RolloutConfig

    n, seed, m_push = args.episodes, args.seed, args.push_episodes
    # the arms as measured: the per-estimate prior (support "table") and FLR's shortlist decided
    # by appearance, the defaults until 2026-11-27, each variant swapping one component; the
    # defaults since (the held prior "table_memory", appearance recognition) are arms of their own
    manifold = dict(
        pose="manifold",
        segmenter=args.segmenter,
        recognize=not args.no_recognize,
        support="table",
        recognizer="flr+appearance",
        calibration="none",
    )
    held = {**manifold, "support": "table_memory"}
    fallback = {**manifold, "fallback_cameras": ("side",)}
    return {
        "oracle": RolloutConfig(pose="oracle", episodes=n, seed=seed),
        "manifold": RolloutConfig(**manifold, episodes=n, seed=seed),
        RESTING_HYPOTHESIS_ARM: RolloutConfig(
            **manifold, resting_hypothesis=True, episodes=n, seed=seed
        ),
        "manifold, no table prior": RolloutConfig(
            **{**manifold, "support": "none"}, episodes=n, seed=seed
        ),
        TABLE_MEMORY_ARM: RolloutConfig(**held, episodes=n, seed=seed),
        TABLE_MEMORY_APPEARANCE_ARM: RolloutConfig(
            **{**held, "recognizer": "appearance"}, episodes=n, seed=seed
        ),
        ARM_CALIBRATION_ARM: RolloutConfig(
            **{**held, "recognizer": "appearance", "calibration": "arm"}, episodes=n, seed=seed
        ),
        RESTING_MODELS_ARM: RolloutConfig(
            **manifold, pose_model=RESTING_MODELS, episodes=n, seed=seed
        ),
        TRUE_POSITION_ARM: RolloutConfig(pose="oracle_position", episodes=n, seed=seed),
        ROTATION_BLIND_ARM: RolloutConfig(**manifold, estimator="chance", episodes=n, seed=seed),
        IMAGE_BLIND_ARM: RolloutConfig(pose="constant", episodes=n, seed=seed),
        "manifold, FLR recognition": RolloutConfig(
            **{**manifold, "recognizer": "flr"}, episodes=n, seed=seed
        ),
        "manifold, appearance recognition": RolloutConfig(
            **{**manifold, "recognizer": "appearance"}, episodes=n, seed=seed
        ),
        "manifold, side fallback": RolloutConfig(**fallback, episodes=n, seed=seed),
        "oracle, push, servoing": RolloutConfig(
            pose="oracle", disturbance="push", episodes=m_push, seed=seed
        ),
        "oracle, push, estimate once": RolloutConfig(
            pose="oracle", disturbance="push", estimate_every=0, episodes=m_push, seed=seed
        ),
        "manifold, push, servoing": RolloutConfig(
            **manifold, disturbance="push", episodes=m_push, seed=seed
        ),
        "manifold, push, estimate once": RolloutConfig(
            **manifold, disturbance="push", estimate_every=0, episodes=m_push, seed=seed
        ),
        "manifold, push, servoing, side fallback": RolloutConfig(
            **fallback, disturbance="push", episodes=m_push, seed=seed
        ),
        "manifold, push, servoing, side fallback, silhouette motion": RolloutConfig(
            **fallback, motion="silhouette", disturbance="push", episodes=m_push, seed=seed
        ),
        "manifold, side fallback, silhouette motion": RolloutConfig(
            **fallback, motion="silhouette", episodes=n, seed=seed
        ),
        "manifold, eye-in-hand camera": RolloutConfig(
            pose="manifold",
            pose_cameras=("eye_in_hand",),
            segmenter="depth",
            support="table",
            recognizer="flr+appearance",
            pose_size=EYE_IN_HAND_SIZE,
            episodes=args.eye_in_hand_episodes,
            seed=seed,
        ),
    }


def _resting_models_file() -> str:
    """The resting-view default models' cache file (trained there on first use)."""
    from scorbot_gym.perception.references import default_models, saved_path
    from scorbot_gym.perception.training import RESTING_TRAINING

    return str(saved_path(default_models("top", 320, 240, training=RESTING_TRAINING)))


def _curves() -> list[tuple[str, float, str, dict]]:
    """The robustness points ``(curve, sigma, label, noisy_oracle parameters)``."""
    curves = []
    for yaw in YAW_SIGMAS:
        noise = {"yaw_sigma_deg": yaw, "pos_sigma_m": 0.0}
        curves.append(("yaw", yaw, f"noisy yaw sigma {yaw:g} deg", noise))
    for pos_cm in POS_SIGMAS_CM:
        noise = {"yaw_sigma_deg": 0.0, "pos_sigma_m": pos_cm / 100}
        curves.append(("pos", pos_cm, f"noisy pos sigma {pos_cm:g} cm", noise))
    return curves


def _machine(jobs: int) -> dict:
    import scorbot_gym

    return {
        "platform": platform.platform(),
        "cpu_count": os.cpu_count(),
        "load_avg": os.getloadavg(),
        "scorbot_gym": scorbot_gym.__version__,
        "jobs": jobs,
    }


def _merge(parser: argparse.ArgumentParser, args) -> int:
    """Join the reports of runs of disjoint ``--arms`` (or ``--perturbations``) of the same
    episodes into one, as one run over them all would have written it (arms of earlier reports
    under their labels of now, :data:`RENAMED_ARMS`)."""
    from pose.fileio import write_result

    parts = []
    for path in args.merge:
        try:
            parts.append(_part(path))
        except (OSError, ValueError) as exc:
            parser.error(f"--merge: {path} is not a readable JSON ({exc})")
    kinds = {p.get("benchmark") for p in parts}
    if len(kinds) != 1 or not kinds <= {"closed_loop", "closed_loop_perturbations"}:
        parser.error(f"--merge: parts must all be closed_loop or all perturbation runs: {kinds}")
    (kind,) = kinds
    if kind == "closed_loop":  # an arm an earlier report named otherwise gets its label of now
        for part in parts:
            part["arms"] = {RENAMED_ARMS.get(k, k): a for k, a in part["arms"].items()}
            for label, arm in part["arms"].items():
                arm["label"] = label
    same = ("seed", "episodes_per_arm", "episodes_per_disturbed_arm", "arm")
    same += ("support", "recognizer", "calibration")
    for key in same:
        if len({json.dumps(p.get(key)) for p in parts}) > 1:
            parser.error(f"--merge: the parts differ in {key!r}: they are not one run's arms")
    labels = [k for p in parts for k in p["arms"]]
    twice = sorted({k for k in labels if labels.count(k) > 1})
    if twice:
        parser.error(f"--merge: arms in more than one part: {twice}")
    if kind == "closed_loop_perturbations" and args.config is None:
        args.config = PERTURBATIONS
    args.out = _out(parser, args, "closed_loop.json")
    report = {k: v for k, v in parts[0].items() if k in ("benchmark", *same)}
    report["pose_model_ready_s"] = max(p["pose_model_ready_s"] for p in parts)
    if kind == "closed_loop_perturbations":
        report["wall_s"] = sum(p["wall_s"] for p in parts)
        report["perturbations"] = [k for p in parts for k in p["perturbations"]]
        report["arms"] = {k: a for p in parts for k, a in p["arms"].items()}
    else:
        arms = {k: a for p in parts for k, a in p["arms"].items()}
        order = list(_arm_configs(args))
        report["arms"] = {k: arms[k] for k in sorted(arms, key=order.index)}
        report["robustness"] = {
            c: [pt for p in parts for pt in p["robustness"][c]] for c in ("yaw", "pos")
        }
        for p in parts:
            if "loop_timing_320x240_one_thread" in p:
                report["loop_timing_320x240_one_thread"] = p["loop_timing_320x240_one_thread"]
        missing = [k for k in order if k not in arms]
        missing += [] if all(report["robustness"].values()) else [ROBUSTNESS]
        if missing:
            print(f"note: no part ran {missing}; the merged report lacks them")
    sources = [  # a part that was itself merged names its own parts
        m for part, path in zip(parts, args.merge, strict=True)
        for m in part.get("machine", {}).get("merged_from") or [str(path)]
    ]  # fmt: skip
    report["machine"] = {**parts[0]["machine"], "merged_from": sources}
    write_result(args.out, report, args.config)
    if args.config is None:  # the figure is the main run's
        _plot(report, args.out.with_suffix(".png"))
        print(f"written {args.out} and {args.out.with_suffix('.png')}")
    else:
        print(f"written {args.out} (config {args.config!r})")
    return 0


def _part(path: Path) -> dict:
    """A part to merge: a report as a run with ``--out PART.json`` wrote it (its main run, or
    the one config it holds)."""
    from pose.fileio import read_json

    data = read_json(path)
    configs = data.pop("configs", {})
    if "arms" not in data and len(configs) == 1:
        return next(iter(configs.values()))
    return data


def _perturbation_labels(parser: argparse.ArgumentParser, args) -> list[str]:
    """The ``--perturbations`` list, each checked (a usage error names the bad one)."""
    if args.perturbations is None:
        return []
    from scorbot_gym.data.perturbations import Perturbation

    if args.arms is not None:
        parser.error("--arms does not apply with --perturbations (it runs the manifold arm)")
    try:
        labels = [label for label, _ in Perturbation.parse_list(args.perturbations)]
    except ValueError as exc:
        parser.error(f"--perturbations: {exc}")
    if not labels:
        parser.error("--perturbations needs at least one perturbation (or none)")
    return labels


def _perturbation_arms(args, labels: list[str], train_s: float) -> int:
    """The ``manifold`` arm of the main run under each env perturbation, on the same episodes."""
    from pose.fileio import write_result
    from scorbot_gym.evaluation.rollout import RolloutConfig

    manifold = dict(
        pose="manifold",
        segmenter=args.segmenter,
        recognize=not args.no_recognize,
        support=args.perturbation_support,
        recognizer=args.perturbation_recognizer,
        calibration=args.perturbation_calibration,
    )
    runs = [
        (label, RolloutConfig(
            **manifold, perturbation=None if label == "none" else label,
            episodes=args.episodes, seed=args.seed,
        ))
        for label in labels
    ]  # fmt: skip
    t0 = time.perf_counter()
    done = _run_arms(runs, args.jobs, args.progress)
    report = {
        "benchmark": "closed_loop_perturbations",
        "arm": "manifold",
        "support": args.perturbation_support,
        "recognizer": args.perturbation_recognizer,
        "calibration": args.perturbation_calibration,
        "episodes_per_arm": args.episodes,
        "seed": args.seed,
        "pose_model_ready_s": train_s,
        "wall_s": time.perf_counter() - t0,
        "perturbations": labels,
        "arms": {label: done[label] for label in labels},
        "machine": _machine(args.jobs),
    }
    write_result(args.out, report, args.config)
    print(f"written {args.out} (config {args.config!r})")
    return 0


def _loop_timing(config, episodes: int) -> dict:
    """Per-stage cost of perception inside the loop at the estimator's resolution, one thread:
    rendering the camera (timed on the simulator, which the env does once per step) and the
    wrapper's own stages, over every estimate and over the valid ones (full pipeline)."""
    import numpy as np

    from scorbot_gym.evaluation.episodes import run_episode

    env = config.make_env()
    policy = config.make_policy(env)
    stages: dict[str, list[float]] = {}
    valid: dict[str, list[float]] = {}
    render_ms: list[float] = []
    camera = config.pose_cameras[0]
    w, h = config.pose_size

    def on_step(obs: dict, info: dict) -> None:
        sim = env.unwrapped.sim  # timing only; this episode's scene (not a stale one)
        t0 = time.perf_counter()
        sim.render(camera, "rgb", w, h)
        render_ms.append((time.perf_counter() - t0) * 1e3)
        p = info["perception"]
        if not p["estimated"]:
            return
        timings = env.get_wrapper_attr("perception_timings")  # wall-clock: not in info
        parts = {
            k: v
            for k, v in timings["timings_ms"].items()
            if k in ("segment", "recognise", "estimate", "support")
        }
        parts["total"] = timings["total_ms"]
        for k, v in parts.items():
            stages.setdefault(k, []).append(v)
            if p["valid"]:
                valid.setdefault(k, []).append(v)

    for i in range(episodes):
        run_episode(env, policy, config.seed + i, on_step=on_step)
    env.close()
    med = lambda xs: float(np.median(xs)) if xs else None  # noqa: E731
    render = med(render_ms)
    out = {
        "render_ms": render,
        "all_estimates_ms": {k: med(v) for k, v in stages.items()},
        "valid_estimates_ms": {k: med(v) for k, v in valid.items()},
        "n_estimates": len(stages.get("total", [])),
        "n_valid": len(valid.get("total", [])),
    }
    full = out["valid_estimates_ms"].get("total")
    out["render_plus_valid_estimate_ms"] = None if full is None else render + full
    return out


def _curve_point(summary: dict) -> dict:
    keys = ("episodes", "success_rate", "success_rate_ci95", "failure_causes")
    return {k: summary[k] for k in keys}


if __name__ == "__main__":
    sys.exit(main())
