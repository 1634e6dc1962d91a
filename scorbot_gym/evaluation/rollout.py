"""A closed-loop rollout as one configuration: which pose source, cameras, identity, disturbance
and policy. The ``rollout`` command and the closed-loop benchmark both build their runs here, so
what the README's main job measures is what the benchmark measures.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

from scorbot_gym.data.perturbations import Perturbation
from scorbot_gym.envs.arguments import tilt_deg
from scorbot_gym.envs.factory import make_env
from scorbot_gym.evaluation.chunks import parallel, run_chunked
from scorbot_gym.evaluation.episodes import EpisodeResult, run_episodes
from scorbot_gym.evaluation.summary import summarize
from scorbot_gym.names import CALIBRATIONS, POLICIES, POSE_ALIASES, SPLITTERS, SUPPORTS
from scorbot_gym.perception.calibration import DEFAULT_CALIBRATION
from scorbot_gym.perception.recognizers import DEFAULT_RECOGNIZER
from scorbot_gym.perception.support import DEFAULT_SUPPORT
from scorbot_gym.policies import RandomPolicy, ScriptedGraspPolicy

#: the pose sources that split a cluttered table into blobs and estimate the named target on
#: one of them (one camera, the default models of every class)
CLUTTER_POSE_SOURCES = ("manifold_clutter", "largest_blob", "random_blob")
#: the pose sources that answer without looking (:mod:`scorbot_gym.perception.constant`): the
#: object's identity must be given
IMAGE_BLIND_POSE_SOURCES = ("constant", "oracle_position")


@dataclass
class RolloutConfig:
    """Everything that defines a closed-loop run (JSON-able, recorded with its summary).

    ``pose_model`` is a model file for ``pose="manifold"``; without it the default models for
    ``pose_cameras[0]`` are trained on first use and cached. The manifold source estimates from
    the first pose camera and recognises on all of them (default: ``top``, plus ``side`` when
    ``recognize``: the top view alone confuses discs and squares); ``fallback_cameras`` get
    default pose models of their own and estimate where the pose camera's estimate is invalid;
    ``motion="silhouette"`` then places a moved object from its silhouette where none can.
    ``segmenter`` and ``recognizer`` name the source's components (defaults: background
    subtraction; recognition by appearance, the class whose pose model explains the most
    keypoints, for ``manifold``, FLR shortlisting three classes that appearance decides among
    for the clutter sources).
    ``noise`` holds the ``noisy_oracle`` parameters (``pos_sigma_m``, ``yaw_sigma_deg``,
    ``dropout``). ``policy`` is ``scripted``, ``random``, ``rl`` (the shipped SB3 residual
    policy: the scripted controller + a learned correction), ``learned`` (the shipped
    stand-alone imitation policy, no scripted controller), a saved policy folder (``scorbot-gym
    train`` or an imitation policy) or a ``scorbot-gym train`` run folder (its ``checkpoint``:
    ``best`` or ``last`` exported policy, with its normalisation); ``action_type=None`` takes
    the learned policy's action type (joint for the others). ``perturbation`` is the env's
    perturbation in the CLI form (``"lighting=0.5,noise_sigma=4"``, see
    :meth:`~scorbot_gym.data.perturbations.Perturbation.parse`), redrawn every episode; the
    pose models stay the unperturbed ones. ``distractors`` other objects (drawn per episode from
    ``objects``) share the table with the target, which is ``target`` in every episode or
    drawn (``pose="manifold"`` then runs ``"manifold_clutter"``, the clutter pipeline);
    ``tilt_deg`` props the target on a stand, tilted that much. ``splitter`` names
    the stage of the clutter sources that splits blobs several objects share
    (:mod:`scorbot_gym.perception.splitters`; ``"none"``: blobs stay whole). ``regrasps`` is
    the scripted controller's retries after its fingers close on nothing
    (:class:`~scorbot_gym.policies.ScriptedGraspPolicy`; ``scripted`` policy only).
    ``support`` is the image-based sources' table-top prior (:mod:`scorbot_gym.perception.support`;
    ``None``: the source's default, ``"table_memory"`` for ``manifold``, ``"table"`` for the
    clutter sources): ``"table_memory"`` decides once an episode, on clear views, whether the
    object rests on the table and then puts every estimate of a resting one on it;
    ``"table"`` puts each estimate near a resting pose on it; ``"none"``.
    ``estimator`` swaps the ``manifold`` source's trained models for a :mod:`pose.registry`
    baseline fitted on the same views (``"chance"``: a constant rotation placed at the mask's
    position, the rotation-blind answer every estimator figure reports beside it;
    :mod:`scorbot_gym.perception.baseline_models`), with
    segmentation and recognition unchanged; ``"manifold"`` (default) keeps the trained ones.
    ``resting_hypothesis`` adds the resting-view default models to the ``manifold`` source as
    its resting hypothesis (``ModelSetPoseSource(resting_models=...)``: their estimate wherever
    the default models answer a pose near a resting one). ``calibration`` is the ``manifold``
    source's camera calibration (:mod:`scorbot_gym.perception.calibration`; ``None``: its
    default where the segmenter is ``"background"``, else ``"none"``): ``"arm"`` re-calibrates
    each fixed pose camera from the arm's silhouette at every estimate, ``"none"`` keeps the
    cameras as calibrated.
    """

    policy: str = "scripted"
    pose: str = "oracle"
    pose_model: str | None = None
    pose_cameras: tuple[str, ...] | None = None
    fallback_cameras: tuple[str, ...] = ()
    motion: str | None = None
    pose_size: tuple[int, int] = (320, 240)
    segmenter: str = "background"
    recognizer: str | None = None
    recognize: bool = False
    estimate_every: int = 1
    disturbance: str | None = None
    noise: dict[str, float] = field(default_factory=dict)
    action_type: str | None = None
    objects: tuple[str, ...] | None = None
    episodes: int = 20
    seed: int = 0
    perturbation: str | None = None
    checkpoint: str = "best"
    distractors: int = 0
    target: str | None = None
    tilt_deg: float = 0.0
    splitter: str = "none"
    regrasps: int = 0
    support: str | None = None
    estimator: str = "manifold"
    resting_hypothesis: bool = False
    calibration: str | None = None

    def __post_init__(self) -> None:
        self.pose = POSE_ALIASES.get(self.pose, self.pose)
        if self.pose == "manifold" and self.distractors:
            self._to_clutter_pipeline()
        if self.perturbation is not None:
            Perturbation.parse(self.perturbation)  # a bad one fails here, before any episode
        if self.policy not in POLICIES and not Path(self.policy).is_dir():
            raise ValueError(
                f"policy must be one of {POLICIES} or a policy directory from `scorbot-gym "
                f"train`, got {self.policy!r}"
            )
        if self.checkpoint not in ("best", "last"):
            raise ValueError(f"checkpoint must be 'best' or 'last', got {self.checkpoint!r}")
        if self.action_type is None:
            learned = self._learned()
            self.action_type = learned.meta["action_type"] if learned else "joint"
        if self.episodes < 1:
            raise ValueError(f"episodes must be >= 1, got {self.episodes}")
        if self.distractors < 0:
            raise ValueError(f"distractors must be >= 0, got {self.distractors}")
        tilt_deg(self.tilt_deg)  # the env's own check, before any model is trained
        if self.target is not None:
            from scorbot_gym.objects import get_object

            self.target = get_object(self.target).name  # KeyError lists the valid names
            if self.objects and self.target not in self.objects:
                raise ValueError(f"target {self.target!r} is not one of objects {self.objects}")
        if isinstance(self.regrasps, bool) or not isinstance(self.regrasps, int):
            raise ValueError(f"regrasps must be an integer >= 0, got {self.regrasps!r}")
        if self.regrasps < 0 or (self.regrasps and self.policy != "scripted"):
            raise ValueError(
                f"regrasps must be >= 0 and applies to the scripted policy only, got "
                f"{self.regrasps} with policy {self.policy!r}"
            )
        if self.estimate_every < 0:
            raise ValueError(
                f"estimate_every must be >= 0 (0: once per episode), got {self.estimate_every}"
            )
        if self.noise and self.pose != "noisy_oracle":
            raise ValueError(
                f"noise parameters only apply to pose 'noisy_oracle', not {self.pose!r}"
            )
        if self.pose in IMAGE_BLIND_POSE_SOURCES and self.recognize:
            raise ValueError(
                f"pose {self.pose!r} reads no image and cannot recognise the object: drop "
                "recognize (the identity is given)"
            )
        if self.pose in CLUTTER_POSE_SOURCES and self.recognize:
            raise ValueError(
                f"pose {self.pose!r} is told the target (the task command) and chooses its blob "
                "itself: drop recognize"
            )
        if self.splitter not in SPLITTERS:
            raise ValueError(f"splitter must be one of {SPLITTERS}, got {self.splitter!r}")
        if self.splitter != "none" and self.pose not in CLUTTER_POSE_SOURCES:
            raise ValueError(
                f"splitter only applies to the clutter pose sources {CLUTTER_POSE_SOURCES}, "
                f"not {self.pose!r}"
            )
        if self.recognizer is None:  # the source's own default recogniser
            manifold = self.pose == "manifold"
            self.recognizer = DEFAULT_RECOGNIZER if manifold else "flr+appearance"
        if self.support is None:  # the source's own default prior
            self.support = DEFAULT_SUPPORT if self.pose == "manifold" else "table"
        if self.support not in SUPPORTS:
            raise ValueError(f"support must be one of {SUPPORTS}, got {self.support!r}")
        if self.support != "table" and self.pose not in ("manifold", *CLUTTER_POSE_SOURCES):
            raise ValueError(
                f"support only applies to the image-based pose sources, not {self.pose!r}"
            )
        if self.calibration is None:  # the source's own default (arm-aware segmenters only)
            arm_aware = self.pose == "manifold" and self.segmenter == "background"
            self.calibration = DEFAULT_CALIBRATION if arm_aware else "none"
        if self.calibration not in CALIBRATIONS:
            raise ValueError(f"calibration must be one of {CALIBRATIONS}, got {self.calibration!r}")
        if self.calibration != "none" and (
            self.pose != "manifold" or self.segmenter != "background"
        ):
            raise ValueError(
                f"calibration {self.calibration!r} re-calibrates the cameras of pose 'manifold' "
                f"from the arm in background subtraction (segmenter 'background'), not pose "
                f"{self.pose!r} with segmenter {self.segmenter!r}"
            )
        if self.estimator != "manifold":
            from pose.registry import make_from_spec

            try:
                make_from_spec(self.estimator)
            except (KeyError, ValueError, TypeError) as exc:
                raise ValueError(
                    f"estimator must be 'manifold' or a pose.registry baseline such as "
                    f"'chance', got {self.estimator!r}: {exc}"
                ) from None
            if self.pose != "manifold" or self.pose_model is not None or self.fallback_cameras:
                raise ValueError(
                    f"estimator {self.estimator!r} swaps the default models of pose 'manifold' "
                    "(no pose_model, no fallback_cameras)"
                )
        if self.resting_hypothesis and (
            self.pose != "manifold" or self.pose_model is not None or self.estimator != "manifold"
        ):
            raise ValueError(
                "resting_hypothesis adds the resting-view default models to pose 'manifold' "
                "with its default models (no pose_model, estimator 'manifold')"
            )
        if self.pose_cameras is None:
            self.pose_cameras = ("top", "side") if self.recognize else ("top",)
        self.pose_cameras = tuple(self.pose_cameras)
        if not self.pose_cameras:
            raise ValueError("pose_cameras must name at least one camera")
        self.fallback_cameras = tuple(self.fallback_cameras)
        if self.fallback_cameras and self.pose != "manifold":
            raise ValueError(f"fallback_cameras only apply to pose 'manifold', not {self.pose!r}")
        if self.motion is not None and self.pose != "manifold":
            raise ValueError(f"motion only applies to pose 'manifold', not {self.pose!r}")
        if self.motion is not None:
            from scorbot_gym.perception.motion import make_motion

            make_motion(self.motion)  # unknown names fail here, before any episode
        if self.pose_cameras[0] in self.fallback_cameras:
            raise ValueError(
                f"fallback_cameras must differ from the pose camera {self.pose_cameras[0]!r}"
            )

    def _to_clutter_pipeline(self) -> None:
        """``manifold`` on a cluttered table is ``manifold_clutter``: the single-object source
        estimates on whichever blob it sees first (issue 50 found it picking distractors in
        most failed episodes), so the natural request gets the pipeline that splits the table into
        blobs, recognises each and estimates the target's. Settings that only the
        single-object source has are refused rather than dropped."""
        single_only = [
            name
            for name, value, default in (
                ("fallback_cameras", tuple(self.fallback_cameras), ()),
                ("motion", self.motion, None),
                ("segmenter", self.segmenter, "background"),
                ("estimator", self.estimator, "manifold"),
                ("resting_hypothesis", self.resting_hypothesis, False),
            )
            if value != default
        ]
        if self.pose_cameras is not None and len(self.pose_cameras) > 1:
            single_only.append("pose_cameras (one camera)")
        if single_only:
            raise ValueError(
                f"pose 'manifold' with distractors runs the clutter pipeline 'manifold_clutter', "
                f"which has no {', '.join(single_only)}: drop them, or use distractors=0"
            )
        self.pose = "manifold_clutter"
        self.recognize = False  # it recognises every blob itself, told only the target

    @property
    def env_id(self) -> str:
        return "ScorbotGraspCartesian-v0" if self.action_type == "cartesian" else "ScorbotGrasp-v0"

    def pose_kwargs(self, progress: bool = False) -> dict[str, Any]:
        if self.pose == "noisy_oracle":
            return dict(self.noise)
        if self.pose == "manifold_clutter":  # one camera; blobs split, each recognised
            return {
                "models": self._models(progress),
                "recognizer": self.recognizer,
                "splitter": self.splitter,
                "support": self.support,
            }
        if self.pose in CLUTTER_POSE_SOURCES:  # the same blobs, chosen without recognition
            return {
                "models": self._models(progress),
                "splitter": self.splitter,
                "support": self.support,
            }
        if self.pose != "manifold":
            return {}
        from scorbot_gym.perception.references import default_models

        w, h = self.pose_size
        if self.pose_model is not None:
            models: Any = self.pose_model
        else:
            models = default_models(self.pose_cameras[0], w, h, progress=progress)
        kwargs = {
            "models": models,
            "segmenter": self.segmenter,
            "recognizer": self.recognizer,
            "cameras": list(self.pose_cameras),
            "motion": self.motion,
            "support": self.support,
            "calibration": self.calibration,
        }
        if self.estimator != "manifold":  # the same source, a baseline's models
            from scorbot_gym.perception.baseline_models import baseline_source_kwargs

            recognizer = self.recognizer if self.recognize else None
            kwargs.update(
                baseline_source_kwargs(
                    self.estimator, models, recognizer, self.pose_cameras, progress=progress
                )
            )
        if self.resting_hypothesis:
            from scorbot_gym.perception.training import RESTING_TRAINING

            kwargs["resting_models"] = default_models(
                self.pose_cameras[0], w, h, progress=progress, training=RESTING_TRAINING
            )
        if self.fallback_cameras:
            kwargs["fallback_models"] = [
                default_models(c, w, h, progress=progress) for c in self.fallback_cameras
            ]
        return kwargs

    def _models(self, progress: bool) -> Any:
        """The pose model file, or the default models for the first pose camera."""
        if self.pose_model is not None:
            return self.pose_model
        from scorbot_gym.perception.references import default_models

        w, h = self.pose_size
        return default_models(self.pose_cameras[0], w, h, progress=progress)

    def make_env(self, progress: bool = False, **env_kwargs: Any):
        """The wrapped env of this configuration (``env_kwargs`` e.g. for rendering)."""
        if self.objects:
            env_kwargs.setdefault("objects", list(self.objects))
        if self.perturbation:
            env_kwargs.setdefault("perturbation", Perturbation.parse(self.perturbation))
        if self.distractors:
            env_kwargs.setdefault("distractors", self.distractors)
        if self.tilt_deg:
            env_kwargs.setdefault("tilt_deg", self.tilt_deg)
        # a policy that reads images (the pixel policy) names the camera and size it needs
        for key, value in getattr(self._learned(), "env_requirements", {}).items():
            env_kwargs.setdefault(key, value)
        return make_env(
            self.env_id,
            pose=self.pose,
            pose_kwargs=self.pose_kwargs(progress),
            estimate_every=self.estimate_every,
            identity="recognize" if self.recognize else "given",
            disturbance=self.disturbance,
            **env_kwargs,
        )

    def _learned(self):
        """The learned policy this configuration runs, if any (loaded once, clear errors)."""
        if self.policy in ("scripted", "random"):
            return None
        if "_loaded_policy" not in self.__dict__:  # not a field: stays out of to_dict()
            from scorbot_gym.policies.loading import load_policy

            self.__dict__["_loaded_policy"] = load_policy(self.policy, self.checkpoint)
        return self.__dict__["_loaded_policy"]

    def make_policy(self, env):
        if self.policy == "random":
            return RandomPolicy(env.action_space, self.seed)
        if self.policy == "scripted":
            return ScriptedGraspPolicy.for_env(env, regrasps=self.regrasps)
        return self._learned().bind(env)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @property
    def reset_options(self) -> dict[str, Any] | None:
        """What every episode's ``reset`` gets: the named target, if any."""
        return {"target": self.target} if self.target else None


def run_rollout(
    config: RolloutConfig, progress: bool = False
) -> tuple[dict[str, Any], list[EpisodeResult]]:
    """Run the configured episodes; returns the summary (with the configuration) and results."""
    results, _ = _episodes(config, progress)
    return rollout_summary(config, results), results


def run_rollouts(
    configs: Sequence[RolloutConfig],
    jobs: int = 1,
    progress: bool = False,
    ray: str | None = None,
) -> list[tuple[dict[str, Any], list[EpisodeResult]]]:
    """:func:`run_rollout` for each configuration, its episodes cut into chunks of seeds run in
    ``jobs`` worker processes, or as Ray tasks with ``ray`` (``"local"`` or a cluster address;
    :func:`scorbot_gym.evaluation.chunks.run_chunked`); the results are the same for any
    ``jobs`` or runner. A summary's ``wall_s`` is the seconds its episodes took, added over
    its chunks (one core's time: a worker runs OpenCV on one thread)."""
    workers = parallel(jobs, ray)

    def chunk_args(i: int, n: int, first: int) -> tuple:
        chunk = replace(configs[i], episodes=n, seed=first)
        return (chunk, False, 1) if workers else (chunk, progress)

    tasks = [(c.episodes, c.seed) for c in configs]
    done = run_chunked(_episodes, tasks, chunk_args, jobs, ray)
    out = []
    for config, chunks in zip(configs, done, strict=True):
        results = [r for rs, _ in chunks for r in rs]
        summary = rollout_summary(config, results)
        summary["wall_s"] = sum(s for _, s in chunks)
        out.append((summary, results))
    return out


def _episodes(
    config: RolloutConfig, progress: bool = False, cv_threads: int | None = None
) -> tuple[list[EpisodeResult], float]:
    """The configured episodes (a worker's chunk under :func:`run_rollouts`) and their seconds."""
    if cv_threads is not None:
        import cv2

        cv2.setNumThreads(cv_threads)
    t0 = time.perf_counter()
    env = config.make_env(progress=progress)
    try:
        policy = config.make_policy(env)
        results = run_episodes(
            env, policy, config.episodes, config.seed, config.reset_options, progress
        )
    finally:
        env.close()
    return results, time.perf_counter() - t0


def rollout_summary(config: RolloutConfig, results: list[EpisodeResult]) -> dict[str, Any]:
    """The summary of ``results`` (:func:`~scorbot_gym.evaluation.summary.summarize`) with the
    configuration that ran them."""
    summary = summarize(results)
    summary.update(
        policy=config.policy,
        pose_source=config.pose,
        estimate_every=config.estimate_every,
        disturbance=config.disturbance,
        perturbation=config.perturbation,
        action_type=config.action_type,
        seed=config.seed,
        config=config.to_dict(),
    )
    return summary
