"""Train SB3 / sb3-contrib agents on the grasping env (the ``scorbot-gym train`` logic).

A run folder holds everything needed to continue or use the run (layout in
:mod:`scorbot_gym.rl.runs`): ``config.json`` (the :class:`TrainConfig` with its hyperparameters
resolved from the shipped YAML files, see :mod:`scorbot_gym.rl.hyperparams`), Monitor CSVs,
the checkpoint (written whole, then swapped in, so a kill leaves one complete; ``state.json``
holds timesteps, training wall time, the evaluation history and the configuration it was
trained with), the last and the best exported policy (see :mod:`scorbot_gym.policies.sb3`) and
TensorBoard logs (every evaluation is dumped as soon as it is made).

``config.json`` is written only once the run has started (settings checked, envs and model
built); a folder whose run stopped before its first checkpoint is started afresh by
:func:`train`, which takes no other folder than a new or empty one (a folder of something
else is refused, untouched). A run folder is locked while a process trains in it (see
:func:`scorbot_gym.rl.runs.claim`). :func:`resume` continues from the last checkpoint up to the
configured number of steps and refuses, with the file and what is wrong, damaged files or a
changed configuration.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import re
import shutil
import warnings
from concurrent.futures import as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import yaml
from stable_baselines3.common.vec_env import VecEnvWrapper

from pose.fileio import atomic_write_bytes, atomic_write_json
from scorbot_gym import seeds as seed_ranges
from scorbot_gym.envs.factory import make_env
from scorbot_gym.names import IDENTITIES
from scorbot_gym.objects import CATALOGUE
from scorbot_gym.policies.sb3 import FORMAT, VERSION, ObservationNormalizer, SB3Policy
from scorbot_gym.policies.sb3_files import MODEL_FILE, old_format_message, save_model
from scorbot_gym.rl import checkpoint, runs
from scorbot_gym.rl import hyperparams as hparams
from scorbot_gym.rl.callbacks import (
    CheckpointCallback,
    SuccessEvalCallback,
    TrainingClock,
    atomic_save,
)
from scorbot_gym.rl.hyperparams import ALGOS, POSES
from scorbot_gym.rl.residual import ResidualActionWrapper
from scorbot_gym.tasks.grasp import REWARD_GAMMA

#: the evaluations during training use these seeds; no training episode does (scorbot_gym.seeds)
EVAL_SEED = seed_ranges.TRAINING_EVALUATION.start
#: settings a resumed run may change (how long, how often to evaluate and save, logging);
#: any other difference from the checkpoint's configuration is refused
RESUMABLE_CHANGES = (
    "timesteps",
    "eval_every",
    "eval_episodes",
    "checkpoint_every",
    "progress_bar",
    "torch_threads",
    "tensorboard",
    "device",
)


def best_checkpoint(state: dict[str, Any]) -> dict[str, Any]:
    """What a run's ``best/`` policy is: the weights of the evaluation with the highest
    success so far (the latest among equals), on the run's training-evaluation seeds, which
    no reported comparison uses (:data:`scorbot_gym.seeds.TRAINING_EVALUATION`)."""
    data = (state.get("provenance") or {}).get("data") or {}
    return {
        "kind": "best",
        "chosen_by": "the highest evaluation success during training (the latest among equals)",
        "evaluation": dict(state["best"]),
        "evaluation_seeds": data.get("evaluation_seeds"),
    }


@dataclass
class TrainConfig:
    """Everything a run depends on (saved as ``config.json``; the run is a function of it).

    ``hyperparams`` overrides the entry of the shipped ``hyperparams/<algo>.yml`` for the
    setting (``residual`` or ``default``); :meth:`resolved` fills in the rest, and a run
    records the resolved set, so it does not change with the package's defaults.
    """

    algo: str = "sac"
    pose: str = "oracle"
    pose_model: str | None = None  # model file for pose="manifold" (None: the default models)
    #: pose="manifold": what its estimator is told of the object: "recognize" (recognised from
    #: the images, no privileged input: the default, recorded as such by :meth:`resolved`) or
    #: "given" (privileged: told the true class, for ablations); None for the other poses
    identity: str | None = None
    noise_pos_m: float = 0.01  # pose="noisy" or "occluded": x-y position noise (std)
    noise_yaw_deg: float = 5.0  # pose="noisy" or "occluded": heading noise (std)
    #: pose="occluded": the object is hidden while the hand is within a distance drawn per
    #: episode from [hide_low_m, hide_high_m] of it (OccludedOraclePoseSource)
    hide_low_m: float = 0.06
    hide_high_m: float = 0.2
    action_type: str = "cartesian"
    objects: list[str] | None = None  # training objects (default: the whole catalogue)
    classes: list[str] | None = None  # entries of the object_class one-hot (default: catalogue)
    timesteps: int = 20_000
    seed: int = 0
    n_envs: int = 1
    residual: bool = False
    residual_scale: float = 0.3
    residual_gripper: bool = False  # the residual corrects the gripper too (ResidualActionWrapper)
    bc_demos: int = 0
    bc_steps: int = 2000
    init_policy: str | None = None  # fine-tune this imitation policy ("learned" or a folder)
    #: start from this RL policy's networks and observation statistics (a shipped name such
    #: as "rl_scratch", or a policy folder of the same algorithm, action type and network),
    #: with a new replay buffer: e.g. to go on training under another pose source
    init_weights: str | None = None
    #: the entry of hyperparams/<algo>.yml (None: 'residual', 'finetune' or 'default' by kind)
    hyperparams_entry: str | None = None
    hyperparams: dict[str, Any] = field(default_factory=dict)
    normalize: bool = True
    eval_every: int = 5000
    eval_episodes: int = 20
    checkpoint_every: int = 5000
    progress_bar: bool = True
    torch_threads: int = 1  # more threads slow small-network updates on a shared machine
    tensorboard: bool = True
    device: str = "auto"  # where networks update: "auto" (CUDA if there is one), "cpu", "cuda:N"

    def validate(self) -> TrainConfig:
        """Check every setting (one-line errors naming it); hyperparameters included."""
        self._check_types()
        if self.algo not in ALGOS:
            raise ValueError(f"algo must be one of {ALGOS}, got {self.algo!r}")
        if self.pose not in POSES:
            raise ValueError(f"pose must be one of {POSES}, got {self.pose!r}")
        if self.pose != "manifold" and self.pose_model:
            raise ValueError(f"pose_model only applies to pose 'manifold', not {self.pose!r}")
        if self.identity not in (None, *IDENTITIES):
            raise ValueError(f"identity must be one of {IDENTITIES}, got {self.identity!r}")
        if self.pose != "manifold" and self.identity is not None:
            raise ValueError(
                f"identity only applies to pose 'manifold', not {self.pose!r} (the oracle and "
                "noisy poses read the ground truth)"
            )
        if self.action_type not in ("cartesian", "joint"):
            raise ValueError(
                f"action_type must be 'cartesian' or 'joint', got {self.action_type!r}"
            )
        for name, low in (
            ("timesteps", 1),
            ("n_envs", 1),
            ("eval_every", 1),
            ("eval_episodes", 1),
            ("checkpoint_every", 1),
            ("bc_demos", 0),
            ("bc_steps", 0),
            ("torch_threads", 0),
        ):
            if getattr(self, name) < low:
                raise ValueError(f"{name} must be an integer >= {low}, got {getattr(self, name)}")
        for name, low_open in (
            ("residual_scale", True),
            ("noise_pos_m", False),
            ("noise_yaw_deg", False),
            ("hide_low_m", False),
            ("hide_high_m", False),
        ):
            value = getattr(self, name)
            if not (math.isfinite(value) and (value > 0 if low_open else value >= 0)):
                bound = "> 0" if low_open else ">= 0"
                raise ValueError(f"{name} must be a finite number {bound}, got {value}")
        if self.hide_low_m > self.hide_high_m:
            raise ValueError(
                f"hide_low_m ({self.hide_low_m}) must be <= hide_high_m ({self.hide_high_m})"
            )
        seed_ranges.check_run_seed(self.seed)
        for name in self.objects or []:
            if name not in CATALOGUE:
                raise ValueError(f"unknown object {name!r}; catalogue: {', '.join(CATALOGUE)}")
        if self.residual_gripper and not self.residual:
            raise ValueError("residual_gripper applies only to a residual run (residual=True)")
        if not re.fullmatch(r"auto|cpu|cuda(:\d+)?", self.device):
            raise ValueError(
                f"device must be 'auto', 'cpu', 'cuda' or 'cuda:N', got {self.device!r}"
            )
        if self.init_policy is not None:
            self._check_finetune()
        if self.init_weights is not None:
            self._check_init_weights()
        hp = self.resolved_hyperparams()
        if hp.get("object_features") == "grasp_frame" and self.finetune:
            raise ValueError(
                "object_features grasp_frame does not apply to --init-policy: the imitation "
                "policy's own features are used (a grasp-frame imitation policy reads the frame)"
            )
        return self

    @property
    def finetune(self) -> bool:
        """Whether this run fine-tunes an imitation policy (:mod:`scorbot_gym.rl.finetune`)."""
        return self.init_policy is not None

    def init_weights_folder(self) -> Path:
        """The policy folder :attr:`init_weights` names (a shipped name or a path)."""
        from scorbot_gym.policies.loading import SHIPPED

        return runs.policy_dir(Path(SHIPPED.get(self.init_weights, self.init_weights)))

    def _check_init_weights(self) -> None:
        """The initial policy must be one this run's model can take whole: same algorithm,
        action type and network, trained with normalised observations, no residual."""
        if self.residual or self.init_policy is not None:
            raise ValueError("init_weights excludes residual and init_policy")
        if not self.normalize:
            raise ValueError(
                "init_weights needs normalize=true (it starts from the policy's observation "
                "statistics)"
            )
        folder = self.init_weights_folder()
        meta = runs.read_json(folder / "policy.json")
        if not isinstance(meta, dict):
            raise ValueError(f"init_weights: {folder}/policy.json is not a policy description")
        theirs = {
            "algo": meta.get("algo"),
            "action_type": meta.get("action_type"),
            "net_arch": list((meta.get("config") or {}).get("hyperparams", {}).get("net_arch", [])),
            "residual": meta.get("residual"),
        }
        ours = {
            "algo": self.algo,
            "action_type": self.action_type,
            "net_arch": list(self.resolved_hyperparams()["net_arch"]),
            "residual": None,
        }
        for key, value in ours.items():
            if theirs[key] != value:
                raise ValueError(
                    f"init_weights {self.init_weights}: its {key} is {theirs[key]!r}, this "
                    f"run's {value!r}"
                )
        if not (folder / "normalize.npz").is_file():
            raise ValueError(f"init_weights {self.init_weights}: {folder} has no normalize.npz")

    def _check_finetune(self) -> None:
        if self.algo != "sac":
            raise ValueError(f"init_policy fine-tunes with algo 'sac', got {self.algo!r}")
        if self.residual:
            raise ValueError(
                "init_policy and residual exclude each other (a fine-tuned policy acts alone)"
            )
        if self.normalize:
            raise ValueError(
                "normalize must be false with init_policy (the features are "
                "normalised with the initial policy's statistics)"
            )
        from scorbot_gym.rl.finetune import load_init_policy

        init = load_init_policy(self.init_policy, self.action_type)
        hidden = list(init.meta["network"]["hidden"])
        hp = hparams.resolve(
            self.algo, self.residual, self.hyperparams, True, self.hyperparams_entry
        )
        if list(hp["net_arch"]) != hidden:
            raise ValueError(
                f"net_arch must be the initial policy's hidden layers {hidden} to "
                f"fine-tune it, got {hp['net_arch']}"
            )

    def _check_types(self) -> None:
        """A hand-edited config.json fails here, naming the key, rather than deep in SB3."""
        kinds = {int: "an integer", float: "a number", bool: "true or false", str: "a string"}
        for f in dataclasses.fields(self):
            value, default = getattr(self, f.name), f.default
            if f.name == "hyperparams":
                ok = isinstance(value, dict)
                kind = "a mapping"
            elif f.name in ("objects", "classes"):
                ok = value is None or (
                    isinstance(value, list) and all(isinstance(v, str) for v in value)
                )
                kind = "a list of names"
            elif f.name in ("pose_model", "init_policy", "init_weights"):
                ok, kind = value is None or isinstance(value, str), "a path"
            elif f.name == "identity":
                ok, kind = value is None or isinstance(value, str), f"one of {IDENTITIES}"
            elif f.name == "hyperparams_entry":
                ok, kind = value is None or isinstance(value, str), "an entry name"
            else:
                want = type(default)
                kind = kinds[want]
                ok = isinstance(value, want) and not (want is int and isinstance(value, bool))
                if want is float and isinstance(value, int) and not isinstance(value, bool):
                    ok = True
            if not ok:
                raise ValueError(f"{f.name} must be {kind}, got {value!r}")

    def resolved_hyperparams(self) -> dict[str, Any]:
        """The shipped entry of this run updated by its ``hyperparams`` (checked)."""
        return hparams.resolve(
            self.algo, self.residual, self.hyperparams, self.finetune, self.hyperparams_entry
        )

    @property
    def setting(self) -> str:
        """The name of the hyperparameter entry this run uses."""
        return hparams.setting_for(self.residual, self.finetune, self.hyperparams_entry)

    def resolved(self) -> TrainConfig:
        """A copy whose ``hyperparams`` is the full set the run uses, and whose ``identity`` says
        what a manifold pose is told (so a run records it, whatever the default becomes)."""
        hp = self.resolved_hyperparams()
        identity = self.pose_identity if self.pose == "manifold" else None
        return dataclasses.replace(self, hyperparams=hp, identity=identity)

    @property
    def pose_identity(self) -> str:
        """``make_env``'s ``identity``: a manifold pose recognises the object unless the run
        opted into ``"given"``; the oracle and noisy poses read the ground truth ("given")."""
        if self.pose != "manifold":
            return "given"
        return self.identity or "recognize"

    @property
    def env_id(self) -> str:
        return "ScorbotGraspCartesian-v0" if self.action_type == "cartesian" else "ScorbotGrasp-v0"

    def class_names(self) -> list[str]:
        return list(self.classes) if self.classes else list(CATALOGUE)

    def pose_args(self) -> tuple[str, dict[str, Any]]:
        if self.pose == "noisy":
            return "noisy_oracle", {
                "pos_sigma_m": self.noise_pos_m,
                "yaw_sigma_deg": self.noise_yaw_deg,
            }
        if self.pose == "occluded":
            return "occluded_oracle", {
                "pos_sigma_m": self.noise_pos_m,
                "yaw_sigma_deg": self.noise_yaw_deg,
                "hide_distance_m": [self.hide_low_m, self.hide_high_m],
            }
        if self.pose == "manifold":
            if self.pose_model:
                models: Any = self.pose_model
            else:
                from scorbot_gym.perception.training import default_pose_models

                # The top camera's default models, as `scorbot-gym rollout` uses: trained on
                # first use and cached, so a resumed run and its evaluation read the same ones.
                models = default_pose_models(progress=False)
            if self.pose_identity == "given":  # privileged: the top camera, told the class
                return "manifold", {"models": models}
            from scorbot_gym.evaluation import compare  # lazily: evaluation imports rl

            # no privileged input, as `rollout --pose manifold` and compare's manifold: masks
            # by background subtraction, the identity recognised over the top and side views
            return "manifold", {
                "models": models,
                "segmenter": compare.MANIFOLD_SEGMENTER,
                "recognizer": compare.MANIFOLD_RECOGNIZER,
                "cameras": list(compare.MANIFOLD_CAMERAS),
            }
        return "oracle", {}

    def schedule(self) -> dict[str, Any]:
        """SB3's arguments for this many envs and the updates per env step they give."""
        hp = self.resolved_hyperparams()
        return hparams.sb3_schedule(self.algo, hp, self.n_envs)

    def to_json(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> TrainConfig:
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"unknown training settings {unknown}; valid: {sorted(known)}")
        return cls(**cls.as_older_runs_meant(data)).validate()

    @staticmethod
    def as_older_runs_meant(data: dict[str, Any]) -> dict[str, Any]:
        """``data`` with the settings a run from before them implies (not today's defaults)."""
        if data.get("residual") and "residual_gripper" not in data:
            data = {**data, "residual_gripper": True}  # the residual corrected the gripper then
        # runs from before these settings: the kind's entry, updates on the CPU, and a
        # manifold pose told the object's class (the estimator recognised nothing then)
        identity = "given" if data.get("pose") == "manifold" else None
        data = {"hyperparams_entry": None, "device": "cpu", "identity": identity, **data}
        hp = data.get("hyperparams")
        if isinstance(hp, dict) and hp:  # a resolved set from before these keys: their values
            # then (not the entry's now)
            then = {
                "reward_type": "dense",
                "reward_scale": 1.0,
                "object_features": "class",
                "reward_gamma": REWARD_GAMMA,
            }
            data = {**data, "hyperparams": {**then, **hp}}
        return data


def check_pose_model(config: TrainConfig) -> None:
    """Load the pose model file once, before anything is written: a damaged or wrong file is
    a one-line error here rather than a traceback from an env worker."""
    if config.pose != "manifold" or not config.pose_model:
        return  # no file: the default models, trained on first use and cached
    from pose.model_set import PoseModelSet

    path = Path(config.pose_model)
    if not path.is_file():
        raise FileNotFoundError(f"pose model {path}: no such file")
    try:
        PoseModelSet.load(path)
    except Exception as exc:  # numpy/zip/JSON errors of many kinds on a damaged file
        raise ValueError(
            f"pose model {path} is not a model file from `scorbot-gym pose train` "
            f"({type(exc).__name__}: {exc})"
        ) from None


def make_policy_env(config: TrainConfig, objects: list[str] | None = None) -> gym.Env:
    """The env a policy of this run acts in (observations as in training, no residual)."""
    pose, kwargs = config.pose_args()
    return make_env(
        config.env_id,
        pose=pose,
        pose_kwargs=kwargs,
        identity=config.pose_identity,
        classes=config.class_names(),
        objects=objects if objects is not None else config.objects,
        reward_type=config.resolved_hyperparams()["reward_type"],
        reward_gamma=config.resolved_hyperparams().get("reward_gamma", REWARD_GAMMA),
    )


def make_training_env(config: TrainConfig) -> gym.Env:
    """One training env: the policy env, wrapped as a residual problem if asked, or as the
    initial imitation policy's features when fine-tuning it."""
    env = make_policy_env(config)
    if config.residual:
        env = ResidualActionWrapper(
            env, scale=config.residual_scale, gripper=config.residual_gripper
        )
    if config.resolved_hyperparams().get("object_features", "class") == "grasp_frame":
        from scorbot_gym.policies.object_features import GraspFrameObservation

        # outside the residual wrapper: its scripted base reads the class one-hot
        env = GraspFrameObservation(env)
    if config.finetune:
        from scorbot_gym.rl.finetune import ImitationFeatures, load_init_policy

        env = ImitationFeatures(env, load_init_policy(config.init_policy))
    return env


def _monitored(config: TrainConfig, filename: str | None, objects: tuple = ()) -> gym.Env:
    """A monitored training env; ``objects`` (user-registered ObjectSpecs) are installed first,
    as a spawned ``SubprocVecEnv`` worker imports the built-in catalogue only."""
    from stable_baselines3.common.monitor import Monitor

    from scorbot_gym.objects import install_objects

    install_objects(objects)
    # every segment (the first run, each resume) starts a file of its own (see monitor_segment)
    return Monitor(
        make_training_env(config),
        filename=filename,
        info_keywords=("is_success",),
        override_existing=True,
    )


def monitor_segment(monitor_dir: Path) -> int:
    """The index of the next Monitor segment in ``monitor_dir``: 0 for a new run, then 1, 2, ...

    SB3's Monitor writes ``t`` relative to its file's ``t_start`` header, and appending to a
    file after a resume would restart ``t`` under the old header; so each segment writes
    ``env_<i>.resume<k>.monitor.csv`` with a header of its own, and
    ``stable_baselines3.common.monitor.load_results`` orders all episodes by absolute time."""
    monitor_dir = Path(monitor_dir)
    if not (monitor_dir / "env_0.monitor.csv").is_file():
        return 0
    done = [p.name.split(".")[1] for p in monitor_dir.glob("env_0.resume*.monitor.csv")]
    return 1 + max((int(k[6:]) for k in done if k[6:].isdigit()), default=0)


def make_vec_env(config: TrainConfig, monitor_dir: Path | None = None, segment: int = 0):
    """``n_envs`` training envs (``SubprocVecEnv``; ``DummyVecEnv`` for one), normalised;
    with ``monitor_dir``, each env logs its episodes to ``monitor_dir/env_<i>.monitor.csv``
    (segment 0) or ``env_<i>.resume<segment>.monitor.csv`` (a resumed run)."""
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecNormalize

    if config.n_envs > 1:
        config.pose_args()  # default pose models are trained here once, not by every worker
    if monitor_dir is not None:
        Path(monitor_dir).mkdir(parents=True, exist_ok=True)
    from scorbot_gym.objects import user_objects

    objects = user_objects()
    suffix = f".resume{segment}" if segment else ""
    fns = [
        functools.partial(
            _monitored,
            config,
            str(Path(monitor_dir) / f"env_{i}{suffix}") if monitor_dir else None,
            objects,
        )
        for i in range(config.n_envs)
    ]
    venv = DummyVecEnv(fns) if config.n_envs == 1 else SubprocVecEnv(fns, start_method="spawn")
    if reward_scale(config) != 1.0:
        venv = ScaledReward(venv, reward_scale(config))
    if config.normalize:
        venv = VecNormalize(venv, norm_obs=True, norm_reward=False)
    return venv


def seed_training_envs(model, config: TrainConfig, segment: int = 0) -> None:
    """Seed the first reset of every training env from the run's ``TRAINING_ENVS`` block
    (SB3 seeds them with the model's seed, whose placements are evaluation seeds); a resumed
    segment takes the next seeds, so it does not replay the first episodes' placements."""
    n = config.n_envs
    model.get_env().seed(seed_ranges.TRAINING_ENVS.block(config.seed, n, segment * n).start)


def trained_by(config: TrainConfig) -> str:
    """How a run's policy is trained (:data:`scorbot_gym.rl.provenance.TRAINED_BY`)."""
    if config.finetune:
        return "rl_finetune"
    return "residual" if config.residual else "rl_from_scratch"


def run_provenance(config: TrainConfig, env: gym.Env) -> dict[str, Any]:
    """The ``provenance`` of a run's policies (:mod:`scorbot_gym.rl.provenance`): this
    command and code, the seeds its episodes came from, and the pose models it observed."""
    from scorbot_gym.rl import provenance

    n_demos = config.bc_demos
    data = {
        "pose": config.pose,
        **({"identity": config.pose_identity} if config.pose == "manifold" else {}),
        "objects": config.objects or "catalogue",
        "training_env_first_resets": provenance.seed_span(
            seed_ranges.TRAINING_ENVS.block(config.seed, config.n_envs)
        ),
        "demonstrations": provenance.seed_span(
            seed_ranges.DEMONSTRATIONS.block(config.seed, n_demos)
        ),
        "evaluation_seeds": provenance.seed_span(
            range(EVAL_SEED, EVAL_SEED + config.eval_episodes)
        ),
    }
    if config.finetune:
        from scorbot_gym.policies.loading import SHIPPED

        path = SHIPPED.get(config.init_policy, config.init_policy)
        init = runs.policy_dir(Path(path))
        data["init_policy"] = {
            "name": config.init_policy,
            **provenance.policy_identity(init, runs.read_json(init / "policy.json")),
        }
    if config.init_weights is not None:
        init = config.init_weights_folder()
        data["init_weights"] = {
            "name": config.init_weights,
            **provenance.policy_identity(init, runs.read_json(init / "policy.json")),
        }
    if config.pose_model:
        models = provenance.pose_model_identity(config.pose_model)
    else:
        models = provenance.env_pose_models(env)
    return provenance.record(trained_by(config), data, models)["provenance"]


class ScaledReward(VecEnvWrapper):
    """A VecEnv whose rewards are ``scale`` times its wrapped one's (the ``reward_scale``
    hyperparameter): what the learner sees; the envs' Monitors log the env's own reward."""

    def __init__(self, venv, scale: float) -> None:
        super().__init__(venv)
        self.scale = float(scale)

    def reset(self):
        return self.venv.reset()

    def step_wait(self):
        obs, rewards, dones, infos = self.venv.step_wait()
        return obs, rewards * self.scale, dones, infos


def reward_scale(config: TrainConfig) -> float:
    """What the learner's rewards are times (``reward_scale``; 1 unless the entry says)."""
    return float(config.resolved_hyperparams().get("reward_scale", 1.0))


def policy_meta(
    config: TrainConfig, env: gym.Env, timesteps: int, provenance: dict[str, Any] | None = None
) -> dict[str, Any]:
    """``policy.json``: how to rebuild the policy's inputs, what it saw in training, and how it
    was made (``trained_by``; ``provenance``, :func:`run_provenance`, if given)."""
    shapes = {k: list(s.shape) for k, s in env.observation_space.spaces.items()}
    residual = None
    if config.residual:
        attr = env.get_wrapper_attr
        residual = {
            "scale": config.residual_scale,
            "gripper": config.residual_gripper,
            "base": {
                "action_type": attr("action_type"),
                "dt": float(attr("dt")),
                "max_joint_step": float(attr("max_joint_step")),
                "max_cartesian_step": float(attr("max_cartesian_step")),
                "max_angle_step": float(attr("max_angle_step")),
                "classes": config.class_names(),
            },
        }
    return {
        "format": FORMAT,
        "version": VERSION,
        "algo": config.algo,
        "uses_scripted_controller": bool(config.residual),  # at test time (a residual's base)
        "action_type": config.action_type,
        "classes": config.class_names(),
        "observation_shapes": shapes,
        "residual": residual,
        "normalize": bool(config.normalize),  # normalize.npz must then travel with the model
        "trained_timesteps": int(timesteps),
        "saw_scripted_controller": {
            "residual_base": bool(config.residual),
            "bc_demo_episodes": int(config.bc_demos),
        },
        "config": config.to_json(),
        "trained_by": trained_by(config),
        **({"provenance": provenance} if provenance is not None else {}),
    }


def _zero_init_actor(model, log_std_init: float) -> None:
    """Start a residual actor at zero output with small noise, i.e. at the base controller."""
    import torch as th

    with th.no_grad():
        if hasattr(model, "actor"):  # SAC / TQC
            for p in model.actor.mu.parameters():
                p.zero_()
            model.actor.log_std.weight.zero_()
            model.actor.log_std.bias.fill_(log_std_init)
        else:  # PPO
            for p in model.policy.action_net.parameters():
                p.zero_()
            model.policy.log_std.fill_(log_std_init)


def build_model(config: TrainConfig, venv, tb_dir: Path | None, new: bool = True):
    """The SB3 model of ``config`` (hyperparameters resolved, see :meth:`TrainConfig.schedule`
    for how they map onto SB3's per-vector-step arguments); a ``new`` run starts from
    ``init_weights`` where given (a resumed one from its checkpoint)."""
    from stable_baselines3 import PPO

    hp = config.resolved_hyperparams()
    sched = hparams.sb3_schedule(config.algo, hp, config.n_envs)
    policy_kwargs: dict[str, Any] = {"net_arch": list(hp["net_arch"])}
    for key in ("log_std_init", "n_critics", "n_quantiles"):
        if key in hp:
            policy_kwargs[key] = hp[key]
    common = {
        "policy": "MultiInputPolicy",
        "env": venv,
        "learning_rate": hp["learning_rate"],
        "gamma": hp["gamma"],
        "ent_coef": hp["ent_coef"],
        "policy_kwargs": policy_kwargs,
        "seed": config.seed,
        "verbose": 0,
        "device": config.device,
        "tensorboard_log": str(tb_dir) if tb_dir else None,
    }
    if config.algo == "ppo":
        ppo_keys = ("n_epochs", "gae_lambda", "clip_range", "vf_coef", "max_grad_norm")
        model = PPO(
            n_steps=sched["n_steps_per_env"],
            batch_size=sched["batch_size"],
            **{k: hp[k] for k in ppo_keys if k in hp},
            **common,
        )
    elif config.finetune:
        return _build_finetune_model(config, hp, sched, common)
    else:
        cls = _model_class(config, hp)
        keys = ("tau", "buffer_size", "batch_size", "learning_starts", "target_update_interval")
        keys += ("target_entropy", "top_quantiles_to_drop_per_net", *hparams.WARMUP_KEYS)
        extra = {k: hp[k] for k in keys if k in hp}
        model = cls(
            train_freq=sched["train_freq"],
            gradient_steps=sched["gradient_steps"],
            **extra,
            **common,
        )
    if config.residual:
        _zero_init_actor(model, hp["log_std_init"])
    if new and config.init_weights is not None:
        warm_start(model, venv, config.init_weights_folder())
    return model


def warm_start(model, venv, folder: Path) -> None:
    """Set ``model``'s networks (actor, critics and target critics) and ``venv``'s observation
    statistics to those of the policy in ``folder``. Optimisers, the entropy coefficient and
    the replay buffer start afresh; the statistics count as the policy's env steps, so they
    move as slowly as they would have in its own run."""
    import torch
    from safetensors.numpy import load_file

    weights = load_file(str(folder / "model.safetensors"))
    state = {k.removeprefix("policy/"): torch.as_tensor(v) for k, v in weights.items()}
    try:
        model.policy.load_state_dict(state)
    except RuntimeError as exc:
        first = str(exc).strip().splitlines()[0]
        msg = f"init_weights {folder}: its networks do not fit this run's ({first})"
        raise ValueError(msg) from None
    meta = runs.read_json(folder / "policy.json") or {}
    count = float(meta.get("trained_timesteps") or 1)
    with np.load(folder / "normalize.npz", allow_pickle=False) as stats:
        for key, rms in venv.obs_rms.items():
            if f"mean/{key}" not in stats.files:
                raise ValueError(f"init_weights {folder}: normalize.npz has no statistics of {key}")
            mean, var = stats[f"mean/{key}"], stats[f"var/{key}"]
            if mean.shape != np.shape(rms.mean):
                raise ValueError(
                    f"init_weights {folder}: {key} has shape {mean.shape}, this run's "
                    f"{np.shape(rms.mean)}"
                )
            rms.mean, rms.var, rms.count = mean.astype(np.float64), var.astype(np.float64), count


def _build_finetune_model(config: TrainConfig, hp: dict, sched: dict, common: dict):
    """:class:`~scorbot_gym.rl.finetune.RLPDSAC` with the demonstration-mixing replay buffer,
    its actor initialised from the imitation policy (see :mod:`scorbot_gym.rl.finetune`)."""
    from scorbot_gym.rl.finetune import RLPDSAC, DemoMixReplayBuffer, init_actor, load_init_policy

    keys = ("tau", "buffer_size", "batch_size", "learning_starts", "target_update_interval")
    extra = {k: hp[k] for k in (*keys, "target_entropy") if k in hp}
    model = RLPDSAC(
        train_freq=sched["train_freq"],
        gradient_steps=sched["gradient_steps"],
        replay_buffer_class=DemoMixReplayBuffer,
        replay_buffer_kwargs={"demo_ratio": hp["demo_ratio"]},
        critic_warmup=hp["critic_warmup"],
        bc_coef=hp["bc_coef"],
        actor_learning_rate=hp.get("actor_learning_rate"),
        **extra,
        **{**common, "policy": "MlpPolicy"},
    )
    init_actor(model, load_init_policy(config.init_policy), hp["log_std_init"])
    return model


class _Run:
    """The pieces of one run and how they are saved."""

    def __init__(self, config: TrainConfig, out: Path, model, venv, state: dict) -> None:
        self.config, self.out, self.model, self.venv, self.state = config, out, model, venv, state
        self.state["config"] = config.to_json()  # what the checkpoints are trained with
        self.clock = TrainingClock(state.get("wall_s", 0.0))
        self.eval_env = make_policy_env(config)
        self.meta_env = make_training_env(config)  # observation space incl. base_action
        self._record_provenance()
        self.init_policy = None
        if config.finetune:
            from scorbot_gym.rl.finetune import load_init_policy

            self.init_policy = load_init_policy(config.init_policy)

    def _record_provenance(self) -> None:
        """The run's provenance in its state: made when it starts; a resume adds its own
        command and code under ``resumed``."""
        now = run_provenance(self.config, self.meta_env)
        first = self.state.get("provenance")
        if first is None and self.state.get("timesteps", 0) > 0:  # a checkpoint from before it
            now["first_segment"] = (
                "not recorded (this run was resumed from a checkpoint written before "
                "provenance was recorded): the command and code above are the resume's"
            )
            first = now
        elif first is not None:
            resumed = {k: now[k] for k in ("command", "code", "libraries", "recorded_at")}
            first.setdefault("resumed", []).append(resumed)
        self.state["provenance"] = first or now

    def normalizer(self) -> ObservationNormalizer | None:
        return (
            ObservationNormalizer.from_vec_normalize(self.venv) if self.config.normalize else None
        )

    def policy(self, model):
        """The policy as it is exported: an SB3 policy, or a fine-tune's imitation policy."""
        if self.init_policy is not None:
            return self._finetuned(model)
        return SB3Policy(model, self._meta(model), self.normalizer())

    def _meta(self, model) -> dict[str, Any]:
        meta = policy_meta(
            self.config, self.meta_env, model.num_timesteps, self.state["provenance"]
        )
        # the run's cost travels with the policy (a shipped copy has no run folder beside it)
        meta["training"] = {
            "env_steps": int(model.num_timesteps),
            "wall_time_s": round(self.clock.seconds, 2),
            "seeds": [int(self.config.seed)],
        }
        return meta

    def save(self, model) -> None:
        """A checkpoint, written whole beside the last one and then swapped in
        (:func:`~scorbot_gym.rl.runs.swap_in`): a kill at any moment leaves one complete."""
        ck = self.out / runs.STAGING_CHECKPOINT
        if ck.exists():  # a save killed mid-way, before this process took the folder
            shutil.rmtree(ck)
        ck.mkdir(parents=True)
        save_model(model, ck / checkpoint.MODEL, training=True)
        if getattr(model, "replay_buffer", None) is not None:
            checkpoint.save_replay_buffer(model.replay_buffer, ck / checkpoint.REPLAY_BUFFER)
        if self.config.normalize:
            checkpoint.save_vec_normalize(self.venv, ck / checkpoint.VEC_NORMALIZE)
        self.state.update(timesteps=int(model.num_timesteps), wall_s=round(self.clock.seconds, 2))
        atomic_write_json(ck / runs.STATE, self.state)
        runs.swap_in(self.out)
        self.export(model, self.out / runs.POLICY)

    def save_best(self, model, record: dict[str, Any]) -> None:
        """The policy of the best evaluation so far (``rollout --policy RUN`` loads it); its
        ``policy.json`` says which evaluation chose it (a copy shipped elsewhere keeps that)."""
        self.state["best"] = {k: record[k] for k in ("timesteps", "success_rate", "ci95")}
        self.export(model, self.out / runs.BEST, checkpoint=best_checkpoint(self.state))

    def _finetuned(self, model):
        from scorbot_gym.rl.finetune import to_imitation_policy

        c = self.config
        demos = self.state.get("demos") or {}
        record = {
            "algo": "sac (RLPD-style: demonstrations in every batch, critic warm-up)",
            "init_policy": c.init_policy,
            "demonstration_episodes": int(demos.get("episodes", 0)),
            "demonstration_transitions": int(demos.get("transitions", 0)),
            "env_steps": int(model.num_timesteps),
            "gradient_updates": int(model._n_updates),
            "wall_time_s": round(self.clock.seconds, 2),
            "pose": c.pose,
            "seed": c.seed,
            "hyperparams": c.hyperparams,
        }
        return to_imitation_policy(model, self.init_policy, record, self.state["provenance"])

    def export(self, model, path: Path, checkpoint: dict[str, Any] | None = None) -> None:
        if self.init_policy is not None:  # numpy weights + policy.json, as the imitation trainer
            self._finetuned(model).save(path)
            return
        path.mkdir(parents=True, exist_ok=True)
        atomic_save(path / MODEL_FILE, lambda p: save_model(model, p))
        meta = self._meta(model)
        if checkpoint is not None:
            meta["checkpoint"] = checkpoint
        atomic_write_json(path / "policy.json", meta)
        norm = self.normalizer()
        if norm is not None:
            atomic_save(path / "normalize.npz", norm.save)

    def learn(self, remaining: int) -> None:
        from stable_baselines3.common.callbacks import CallbackList

        c = self.config
        evaluator = SuccessEvalCallback(
            self.eval_env,
            self.policy,
            self.state.setdefault("eval", []),
            self.clock,
            c.eval_every,
            c.eval_episodes,
            EVAL_SEED,
            on_best=self.save_best,
            npz_path=self.out / runs.MONITOR / runs.EVALUATIONS,
        )
        callbacks = CallbackList([evaluator, CheckpointCallback(self.save, c.checkpoint_every)])
        if remaining > 0:
            self.model.learn(
                remaining,
                callback=callbacks,
                progress_bar=c.progress_bar,
                reset_num_timesteps=self.model.num_timesteps == 0,
                tb_log_name="run",
            )
        if not self.state["eval"] or self.state["eval"][-1]["timesteps"] < self.model.num_timesteps:
            if remaining <= 0:  # no learn() call: the model has no logger yet
                from stable_baselines3.common.utils import configure_logger

                tb = str(self.out / runs.TENSORBOARD) if c.tensorboard else None
                self.model.set_logger(configure_logger(0, tb, "run", False))
            evaluator.init_callback(self.model)
            evaluator.evaluate()
        self.save(self.model)

    def close(self) -> None:
        self.venv.close()
        self.eval_env.close()
        self.meta_env.close()


def _seed_with_demos(run: _Run) -> dict[str, Any]:
    """Scripted demonstrations: into the replay buffer (off-policy) and behaviour cloning."""
    from scorbot_gym.rl.demos import add_to_replay_buffer, behaviour_clone, collect_demonstrations

    c = run.config
    if c.finetune:
        return _fill_demo_buffer(run)
    first = seed_ranges.DEMONSTRATIONS.block(c.seed, c.bc_demos).start
    demos = collect_demonstrations(run.meta_env, c.bc_demos, seed=first)
    if c.normalize:
        for k, v in demos.obs.items():
            run.venv.obs_rms[k].update(v)
    demos = dataclasses.replace(demos, rewards=demos.rewards * reward_scale(c))  # as learned
    added = add_to_replay_buffer(run.model, demos) if hasattr(run.model, "replay_buffer") else 0
    losses = behaviour_clone(run.model, demos, run.normalizer(), c.bc_steps, seed=c.seed)
    return {
        "episodes": c.bc_demos,
        "transitions": len(demos),
        "demo_success_rate": demos.success_rate,
        "added_to_replay_buffer": added,
        "bc_loss_first": losses[0] if losses else None,
        "bc_loss_last": losses[-1] if losses else None,
    }


def _fill_demo_buffer(run: _Run) -> dict[str, Any]:
    """Fine-tuning: scripted demonstrations (DART noise as in the imitation trainer) into the
    replay buffer's demonstration part, which every batch samples."""
    from scorbot_gym.rl.finetune import demo_buffer, demo_transitions
    from scorbot_gym.rl.imitation import ImitationConfig, collect_episodes

    c = run.config
    demo_seeds = seed_ranges.DEMONSTRATIONS.block(c.seed, c.bc_demos)
    rng = np.random.default_rng(demo_seeds.start)
    sigma = ImitationConfig().dart_sigma
    episodes = collect_episodes(run.eval_env, demo_seeds, dart_sigma=sigma, rng=rng)
    transitions = demo_transitions(episodes, run.init_policy)
    transitions["rewards"] = transitions["rewards"] * reward_scale(c)  # as the learner sees them
    run.model.replay_buffer.demos = demo_buffer(transitions, run.model)
    return {
        "episodes": c.bc_demos,
        "transitions": len(transitions["actions"]),
        "demo_success_rate": float(np.mean([ep.success for ep in episodes])),
        "dart_sigma": sigma,
        "demo_ratio": c.hyperparams["demo_ratio"],
    }


def _limit_threads(n: int) -> None:
    """Torch's intra-op threads: on busy shared cores, several threads make the updates of
    small networks many times slower than one (see the README's learned-policy section)."""
    import torch as th

    if n > 0:
        th.set_num_threads(n)


def _hyperparams_record(config: TrainConfig, conf: dict[str, Any] | None = None) -> bytes:
    """``hyperparams.yml``: the resolved set, where it came from (the user's ``--conf`` file,
    copied beside it, if any), and SB3's schedule."""
    record = {
        "algo": config.algo,
        "setting": config.setting,
        **({"conf": conf} if conf else {}),
        "n_envs": config.n_envs,
        "hyperparams": config.hyperparams,
        "sb3": config.schedule(),
    }
    return yaml.safe_dump(record, sort_keys=False).encode()


def _read_conf(path: str | Path | None, config: TrainConfig) -> tuple[bytes, dict] | None:
    """The user's hyperparameter file as given (bytes, to copy into the run folder) and its
    record, read before anything is written; ``config`` must already hold its values."""
    if path is None:
        return None
    from scorbot_gym.rl.provenance import file_sha256

    setting = config.setting
    entry = hparams.load_user_file(path, config.algo, setting)  # one-line errors
    differ = sorted(k for k, v in entry.items() if config.hyperparams.get(k) != v)
    overridden = {k: config.hyperparams.get(k) for k in differ}
    record = {
        "file": str(path),
        "copy": runs.CONF,
        "sha256": file_sha256(path),
        "entry": setting,
        **({"overridden_by_hyperparams": overridden} if overridden else {}),
    }
    return Path(path).read_bytes(), record


def train(
    config: TrainConfig, out: str | Path, hyperparams_file: str | Path | None = None
) -> dict[str, Any]:
    """Train from scratch into ``out``; returns the state.

    Every setting is checked and the envs and model are built before ``config.json`` is
    written, so a refused run leaves no half-made run folder behind. ``out`` must be new,
    empty or a run of this tool that stopped before its first checkpoint, and is locked for
    the run's life (:func:`scorbot_gym.rl.runs.claim`). ``hyperparams_file``: the user's
    ``--conf`` file whose values ``config.hyperparams`` holds, copied into the run folder
    (``conf.yml``) and recorded in ``hyperparams.yml``.
    """
    config = config.validate().resolved()
    check_pose_model(config)
    conf = _read_conf(hyperparams_file, config)
    with runs.claim(out, new=True) as out:
        return _train(config, out, conf)


def _train(config: TrainConfig, out: Path, conf: tuple[bytes, dict] | None) -> dict[str, Any]:
    _limit_threads(config.torch_threads)
    venv = make_vec_env(config, out / runs.MONITOR)
    try:
        model = build_model(config, venv, out / runs.TENSORBOARD if config.tensorboard else None)
        seed_training_envs(model, config)
    except BaseException:
        venv.close()
        raise
    state: dict[str, Any] = {"timesteps": 0, "wall_s": 0.0, "eval": []}
    run = _Run(config, out, model, venv, state)
    try:
        atomic_write_json(out / runs.CONFIG, config.to_json())
        if conf is not None:
            atomic_write_bytes(out / runs.CONF, conf[0])
        atomic_write_bytes(out / runs.HYPERPARAMS, _hyperparams_record(config, conf and conf[1]))
        if config.bc_demos:
            run.state["demos"] = _seed_with_demos(run)
        run.save(model)  # resumable from here on
        run.learn(config.timesteps)
    finally:
        run.close()
    return run.state


def train_seeds(
    config: TrainConfig,
    out: str | Path,
    seeds: list[int],
    processes: int = 1,
    hyperparams_file: str | Path | None = None,
    ray: str | None = None,
) -> dict[str, Any]:
    """Train ``config`` once per seed into ``out/seed_<s>/``, ``processes`` seeds at a time
    (each in a process of its own, or a Ray task with ``ray``, see :func:`run_seed_jobs`; 1:
    one after another in this process); ``seeds.json`` records the seeds and the
    configuration, so :func:`resume` continues all of them. ``hyperparams_file`` as for
    :func:`train` (copied into every seed's folder). The folder is locked while it trains.
    Returns ``{"seeds": {seed: state}}``."""
    _check_processes(processes)
    config = _check_seeds(config, seeds, hyperparams_file)
    with runs.claim(out, new=True) as out:
        _write_seeds(out, seeds, config, hyperparams_file)
        return {"seeds": _by_seed(run_seed_jobs(seed_jobs(out), processes, ray))}


def start_seeds(
    config: TrainConfig,
    out: str | Path,
    seeds: list[int],
    hyperparams_file: str | Path | None = None,
) -> TrainConfig:
    """Check ``config`` and write ``out/seeds.json`` (seeds, the resolved configuration and
    the ``--conf`` file), training nothing yet: :func:`seed_jobs` then lists the runs to train
    (each seed's folder is locked while it trains). ``out`` must be new or empty, as for
    :func:`train`. Returns the resolved configuration."""
    config = _check_seeds(config, seeds, hyperparams_file)
    with runs.claim(out, new=True) as out:
        _write_seeds(out, seeds, config, hyperparams_file)
    return config


def _check_seeds(
    config: TrainConfig, seeds: list[int], hyperparams_file: str | Path | None
) -> TrainConfig:
    if not seeds or len(set(seeds)) != len(seeds) or any(s < 0 for s in seeds):
        raise ValueError(f"seeds must be distinct integers >= 0, got {seeds}")
    for s in seeds:
        seed_ranges.check_run_seed(s, "every seed")
    config = config.validate().resolved()
    check_pose_model(config)
    _read_conf(hyperparams_file, config)  # a bad file fails before seeds.json is written
    return config


def _write_seeds(
    out: Path, seeds: list[int], config: TrainConfig, hyperparams_file: str | Path | None
) -> None:
    record: dict[str, Any] = {"seeds": list(seeds), "config": config.to_json()}
    if hyperparams_file is not None:
        record["conf"] = str(Path(hyperparams_file).resolve())
    atomic_write_json(out / runs.SEEDS, record)


def seed_jobs(
    out: str | Path,
    timesteps: int | None = None,
    progress_bar: bool | None = None,
    device: str | None = None,
) -> dict[Path, dict[str, Any]]:
    """The runs of the ``--seeds`` folder ``out``: run folder -> its configuration (seed set;
    ``timesteps``, ``progress_bar``, ``device`` replaced where given; the ``--conf`` file a
    run not started yet copies, under ``hyperparams_file``), for :func:`run_seed_jobs`; a run
    folder with a checkpoint is continued, any other started."""
    out = Path(out)
    record = runs.read_json(out / runs.SEEDS, "the seeds of a multi-seed run")
    seeds = record.get("seeds")
    if not isinstance(seeds, list) or not all(isinstance(s, int) for s in seeds):
        raise ValueError(f"{out / runs.SEEDS}: 'seeds' must be a list of integers")
    try:
        config = TrainConfig.from_json(record.get("config") or {})
    except (TypeError, ValueError) as exc:
        raise ValueError(f"cannot resume: {out / runs.SEEDS}: {exc}") from None
    changes = {"timesteps": timesteps, "progress_bar": progress_bar, "device": device}
    config = dataclasses.replace(config, **{k: v for k, v in changes.items() if v is not None})
    conf = {"hyperparams_file": record["conf"]} if record.get("conf") else {}
    return {
        out / f"seed_{s}": {**dataclasses.replace(config, seed=s).validate().to_json(), **conf}
        for s in seeds
    }


def _check_processes(processes: int) -> None:
    if isinstance(processes, bool) or not isinstance(processes, int) or processes < 1:
        raise ValueError(f"processes must be an integer >= 1, got {processes!r}")


def train_seed(config: dict[str, Any], run: str | Path) -> dict[str, Any]:
    """Train one seed's run (``config`` as in ``config.json``, its ``seed`` set) into ``run``,
    or continue it from its checkpoint to ``config["timesteps"]`` (with its ``progress_bar``
    and ``device``): what a worker of :func:`run_seed_jobs` does, and what a Ray task or a
    cluster job can call; ``config["hyperparams_file"]``, if there, is the ``--conf`` file a
    run not started yet copies."""
    run = Path(run)
    config = dict(config)
    conf = config.pop("hyperparams_file", None)
    if runs.has_checkpoint(run):
        return resume(
            run,
            timesteps=config["timesteps"],
            progress_bar=config["progress_bar"],
            device=config["device"],
        )
    return train(TrainConfig.from_json(config), run, conf)


def _seed_task(job: tuple[dict[str, Any], str]) -> dict[str, Any]:
    """One run as a Ray task: its state, or its error as text (the other tasks go on)."""
    config, run = job
    try:
        return {"state": train_seed({**config, "progress_bar": False}, run)}
    except Exception as exc:  # reported with the others' by run_seed_jobs
        return {"error": f"{type(exc).__name__}: {exc}"}


def run_seed_jobs(
    jobs: dict[Path, dict[str, Any]], processes: int = 1, ray: str | None = None
) -> dict[Path, dict]:
    """Train or continue every run of ``jobs`` (from :func:`seed_jobs`, several folders' may be
    merged), ``processes`` at a time, each in a spawned process that dies with this one (1: one
    after another in this process). A failed run does not stop the others; the failures are
    raised together at the end. Returns run folder -> state.

    ``ray`` runs each run as a Ray task (one CPU) instead, as the sweeps and the comparison do:
    ``"local"`` starts a local Ray instance of ``processes`` CPUs; an address (``"auto"``,
    ``"ray://head:10001"``) joins a cluster, whose workers need the package and must see the
    run folders at the same paths (a shared file system): each task writes its checkpoints
    there, so a stopped cluster job resumes like any other run."""
    _check_processes(processes)
    if ray is None and (processes == 1 or len(jobs) == 1):
        return {run: train_seed(c, run) for run, c in jobs.items()}
    for c in jobs.values():  # default pose models are trained here once, not by every worker
        TrainConfig.from_json(c).pose_args()
    states: dict[Path, dict] = {}
    errors: list[str] = []
    if ray is not None:
        from scorbot_gym.experiments.runners import RayRunner

        local = ray == "local"
        runner = RayRunner(None if local else ray, num_cpus=processes if local else None)
        order = list(jobs)
        outs = runner.map([(jobs[run], str(run)) for run in order], _seed_task)
        for run, out in zip(order, outs, strict=True):
            if "error" in out:
                errors.append(f"{run}: {out['error']}")
            else:
                states[run] = out["state"]
        _raise_failures(errors, len(jobs))
        return {run: states[run] for run in jobs}
    from scorbot_gym.experiments.workers import worker_pool

    with worker_pool(min(processes, len(jobs))) as pool:
        # progress bars of several processes would overwrite each other
        futures = {
            pool.submit(train_seed, {**c, "progress_bar": False}, str(run)): run
            for run, c in jobs.items()
        }
        for future in as_completed(futures):
            run = futures[future]
            try:
                states[run] = future.result()
            except Exception as exc:  # the others go on; every failure is reported below
                errors.append(f"{run}: {type(exc).__name__}: {exc}")
    _raise_failures(errors, len(jobs))
    return {run: states[run] for run in jobs}


def _raise_failures(errors: list[str], n: int) -> None:
    if errors:
        raise RuntimeError(
            f"{len(errors)} of {n} runs failed ({'; '.join(errors)}); the same call, "
            "or --resume of their folder, continues them"
        )


def _by_seed(states: dict[Path, dict]) -> dict[int, dict]:
    return {int(run.name.removeprefix("seed_")): state for run, state in states.items()}


def _read_state(path: Path) -> dict[str, Any]:
    """``state.json``, its structure checked (one-line errors naming the file)."""
    state = runs.read_json(path, "the training state")
    for key, kinds in (("timesteps", int), ("wall_s", (int, float)), ("eval", list)):
        if not isinstance(state.get(key), kinds) or isinstance(state.get(key), bool):
            raise ValueError(
                f"{path}: {key!r} is missing or of the wrong type ({state.get(key)!r})"
            )
    for rec in state["eval"]:
        if not (
            isinstance(rec, dict)
            and isinstance(rec.get("timesteps"), int)
            and isinstance(rec.get("success_rate"), (int, float))
        ):
            raise ValueError(f"{path}: 'eval' must be a list of evaluation records, got {rec!r}")
    return state


def _flat(config: dict[str, Any]) -> dict[str, Any]:
    """``hyperparams`` entries as keys of their own, so a difference names the one that differs."""
    hp = config.get("hyperparams")
    flat = {k: v for k, v in config.items() if k != "hyperparams"}
    if isinstance(hp, dict):
        flat.update({f"hyperparams.{k}": v for k, v in hp.items()})
    else:
        flat["hyperparams"] = hp
    return flat


def _check_compatible(config: dict[str, Any], state: dict[str, Any], out: Path) -> None:
    """Refuse to continue a checkpoint with settings it was not trained with (checked on the
    raw ``config.json``, so that the error names what changed, not what it breaks)."""
    trained = state.get("config")
    if not isinstance(trained, dict):  # a checkpoint from before the configuration was recorded
        return
    now = _flat(TrainConfig.as_older_runs_meant(config))
    trained = _flat(TrainConfig.as_older_runs_meant(trained))
    differ = sorted(
        k
        for k in set(now) | set(trained)
        if k not in RESUMABLE_CHANGES and now.get(k) != trained.get(k)
    )
    if differ:
        detail = ", ".join(f"{k} ({trained.get(k)!r} -> {now.get(k)!r})" for k in differ)
        raise ValueError(
            f"cannot resume {out}: {runs.CONFIG} differs from the checkpoint's configuration in "
            f"{detail}; only {', '.join(RESUMABLE_CHANGES)} may change"
        )


def _warn_filled_defaults(config: TrainConfig, raw: dict[str, Any], path: Path) -> None:
    """Say which settings a run written by an older version lacks: they take today's defaults,
    which need not be what that version did, so a resumed curve may change behaviour there."""
    given = set(TrainConfig.as_older_runs_meant(raw))
    missing = sorted({f.name for f in dataclasses.fields(TrainConfig)} - given)
    if missing:
        filled = ", ".join(f"{k}={getattr(config, k)!r}" for k in missing)
        warnings.warn(
            f"{path} predates the settings {missing}; resuming with today's defaults ({filled})",
            stacklevel=3,
        )


def _remove_orphaned_writes(out: Path) -> int:
    """Delete the temporary files of atomic writes killed mid-way (``.model.tmp<pid>.zip``,
    ``.state.json.tmp``): a run folder is written by its own run only, so none is in use."""
    removed = 0
    for folder in (out, out / runs.CHECKPOINT, out / runs.POLICY, out / runs.BEST):
        for tmp in folder.glob(".*.tmp*"):
            if tmp.is_file():
                tmp.unlink()
                removed += 1
    return removed


def _refuse_old_format(out: Path) -> None:
    """A checkpoint in SB3's pickle-based format is refused before anything of it is read."""
    ck = out / runs.CHECKPOINT
    old = checkpoint.OLD_FILES.items()
    if any((ck / before).is_file() and not (ck / now).is_file() for now, before in old):
        raise ValueError(f"cannot resume: {old_format_message(out, 'training run')}")


def _load_checkpoint(config: TrainConfig, out: Path, venv):
    """The run's model, built from its configuration as :func:`train` builds it, then set to
    the checkpoint: VecNormalize statistics, weights, optimisers, counters, replay buffer. No
    file is unpickled (see :mod:`scorbot_gym.rl.checkpoint`)."""
    from scorbot_gym.policies.sb3_files import restore_training_state

    ck = out / runs.CHECKPOINT
    if config.normalize:
        checkpoint.load_vec_normalize(venv, ck / checkpoint.VEC_NORMALIZE)
    tb_dir = out / runs.TENSORBOARD if config.tensorboard else None
    model = build_model(config, venv, tb_dir, new=False)
    try:
        restore_training_state(model, ck / checkpoint.MODEL)
    except ValueError as exc:
        raise ValueError(f"cannot resume: {exc}") from None
    buffer = getattr(model, "replay_buffer", None)
    if buffer is not None and (ck / checkpoint.REPLAY_BUFFER).is_file():
        checkpoint.load_replay_buffer(buffer, ck / checkpoint.REPLAY_BUFFER)
    return model


def resume(
    out: str | Path,
    timesteps: int | None = None,
    progress_bar: bool | None = None,
    device: str | None = None,
    processes: int = 1,
    ray: str | None = None,
) -> dict[str, Any]:
    """Continue the run in ``out`` from its last checkpoint (to ``timesteps`` in total, default
    the configured number; ``progress_bar`` and ``device`` default as configured); returns the
    state. A ``--seeds`` folder continues every seed, ``processes`` at a time (or as Ray tasks
    with ``ray``, see :func:`run_seed_jobs`). The folder is locked while it trains."""
    _check_processes(processes)
    with runs.claim(out, new=False) as out:
        return _resume(out, timesteps, progress_bar, device, processes, ray)


def _resume(
    out: Path,
    timesteps: int | None,
    progress_bar: bool | None,
    device: str | None,
    processes: int,
    ray: str | None = None,
) -> dict[str, Any]:
    if (out / runs.SEEDS).is_file():
        return _resume_seeds(out, timesteps, progress_bar, device, processes, ray)
    if ray is not None:
        raise ValueError(f"--ray runs the seeds of a --seeds run; {out} is a single run")
    ck = out / runs.CHECKPOINT
    if not (out / runs.CONFIG).is_file():
        raise FileNotFoundError(f"cannot resume {out}: {runs.CONFIG} is missing (not a run folder)")
    runs.settle_checkpoint(out)  # the last complete checkpoint, after a kill mid-save
    _refuse_old_format(out)
    for p in (ck / checkpoint.MODEL, ck / runs.STATE):
        if not p.is_file():
            raise FileNotFoundError(
                f"cannot resume {out}: {p.name} is missing (the run stopped before its first "
                f"checkpoint); start it again with --out {out}"
            )
    config_path = out / runs.CONFIG
    try:
        raw = runs.read_json(config_path, "a training configuration")
        state = _read_state(ck / runs.STATE)
    except ValueError as exc:
        raise ValueError(f"cannot resume: {exc}") from None
    if timesteps is not None:
        if timesteps < 1:
            raise ValueError(f"timesteps must be >= 1, got {timesteps}")
        raw["timesteps"] = int(timesteps)
    if progress_bar is not None:
        raw["progress_bar"] = bool(progress_bar)
    if device is not None:
        raw["device"] = device
    _check_compatible(raw, state, out)
    try:
        config = TrainConfig.from_json(raw)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"cannot resume: {config_path}: {exc}") from None
    _warn_filled_defaults(config, raw, config_path)
    check_pose_model(config)
    if config.normalize and not (ck / checkpoint.VEC_NORMALIZE).is_file():
        raise FileNotFoundError(
            f"cannot resume {out}: {checkpoint.VEC_NORMALIZE} is missing (the run normalises "
            "observations)"
        )
    _remove_orphaned_writes(out)
    _limit_threads(config.torch_threads)
    segment = monitor_segment(out / runs.MONITOR)
    venv = make_vec_env(config, out / runs.MONITOR, segment)
    try:
        model = _load_checkpoint(config, out, venv)
        seed_training_envs(model, config, segment)
    except BaseException:
        venv.close()
        raise
    if timesteps is not None or progress_bar is not None or device is not None:
        atomic_write_json(config_path, config.to_json())
    model._last_obs = None  # the interrupted episode is not continued: start fresh episodes
    run = _Run(config, out, model, venv, state)
    try:
        run.learn(config.timesteps - model.num_timesteps)
    finally:
        run.close()
    return run.state


def _model_class(config: TrainConfig, hp: dict[str, Any] | None = None):
    """The SB3 class of a run. RLPDSAC (SAC whose actor waits ``critic_warmup`` updates for a
    trained critic, then moves with its own step size) where the starting policy is worth
    keeping: a fine-tune's imitation policy, or a run whose entry sets the warm-up keys (the
    residual's zero correction, i.e. the scripted controller)."""
    if hp is None:
        hp = config.resolved_hyperparams()
    if config.finetune or (config.algo == "sac" and any(k in hp for k in hparams.WARMUP_KEYS)):
        from scorbot_gym.rl.finetune import RLPDSAC

        return RLPDSAC
    from scorbot_gym.policies.sb3 import _algorithms

    return _algorithms()[config.algo]


def _resume_seeds(
    out: Path,
    timesteps: int | None,
    progress_bar: bool | None,
    device: str | None = None,
    processes: int = 1,
    ray: str | None = None,
) -> dict[str, Any]:
    if timesteps is not None and timesteps < 1:
        raise ValueError(f"timesteps must be >= 1, got {timesteps}")
    jobs = seed_jobs(out, timesteps, progress_bar, device)
    return {"seeds": _by_seed(run_seed_jobs(jobs, processes, ray))}


__all__ = [
    "ALGOS",
    "POSES",
    "TrainConfig",
    "build_model",
    "check_pose_model",
    "make_policy_env",
    "make_vec_env",
    "resume",
    "run_seed_jobs",
    "seed_jobs",
    "start_seeds",
    "train",
    "train_seed",
    "train_seeds",
]
