"""Train SB3 / sb3-contrib agents on the grasping env (the ``scorbot-gym train`` logic).

A run directory holds everything needed to continue or use the run:

- ``config.json``: the :class:`TrainConfig`;
- ``checkpoint/``: ``model.zip``, ``replay_buffer.pkl`` (off-policy), ``vecnormalize.pkl``,
  each written atomically, and ``state.json`` (timesteps, training wall time, eval history);
- ``policy/``: the exported policy (see :mod:`scorbot_gym.policies.sb3`), rewritten at the end
  and at every checkpoint;
- ``tb/``: TensorBoard logs (``eval/success_rate`` against env steps).

:func:`resume` continues from the last checkpoint up to the configured number of steps.
"""

from __future__ import annotations

import dataclasses
import functools
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym

from pose.fileio import atomic_write_json
from scorbot_gym.envs.factory import make_env
from scorbot_gym.objects import CATALOGUE
from scorbot_gym.policies.sb3 import FORMAT, VERSION, ObservationNormalizer, SB3Policy
from scorbot_gym.rl.callbacks import (
    CheckpointCallback,
    SuccessEvalCallback,
    TrainingClock,
    atomic_save,
)
from scorbot_gym.rl.residual import ResidualActionWrapper

ALGOS = ("sac", "tqc", "ppo")
POSES = ("oracle", "noisy", "manifold")
EVAL_SEED = 1_000_000  # evaluation seeds start here; training episodes never use them


@dataclass
class TrainConfig:
    """Everything a run depends on (saved as ``config.json``; the run is a function of it)."""

    algo: str = "sac"
    pose: str = "oracle"
    pose_model: str | None = None  # model file for pose="manifold"
    noise_pos_m: float = 0.01  # pose="noisy": x-y position noise (std)
    noise_yaw_deg: float = 5.0  # pose="noisy": heading noise (std)
    action_type: str = "cartesian"
    objects: list[str] | None = None  # training objects (default: the whole catalogue)
    classes: list[str] | None = None  # entries of the object_class one-hot (default: catalogue)
    timesteps: int = 20_000
    seed: int = 0
    n_envs: int = 1
    residual: bool = False
    residual_scale: float = 0.3
    bc_demos: int = 0
    bc_steps: int = 2000
    net_arch: list[int] = field(default_factory=lambda: [64, 64])
    learning_rate: float = 3e-4
    batch_size: int = 256
    buffer_size: int = 50_000
    learning_starts: int = 1000
    # SAC/TQC: gradient updates per env step, whatever n_envs is (SB3's default, one update per
    # vector step, would halve it with 2 envs); with n_envs it must give a whole number of
    # updates per vector step, or one update every whole number of vector steps
    updates_per_env_step: float = 1.0
    n_steps: int = 1024  # PPO: env steps per update, over all envs
    ent_coef_init: float = 0.05
    log_std_init: float = -2.0  # of a residual actor: small exploration around the base
    normalize: bool = True
    eval_every: int = 5000
    eval_episodes: int = 20
    checkpoint_every: int = 5000
    progress_bar: bool = True
    torch_threads: int = 1  # more threads slow small-network updates on a shared machine
    tensorboard: bool = True

    def validate(self) -> TrainConfig:
        if self.algo not in ALGOS:
            raise ValueError(f"algo must be one of {ALGOS}, got {self.algo!r}")
        if self.pose not in POSES:
            raise ValueError(f"pose must be one of {POSES}, got {self.pose!r}")
        if self.pose == "manifold" and not self.pose_model:
            raise ValueError("pose='manifold' needs pose_model (from `scorbot-gym pose train`)")
        if self.action_type not in ("cartesian", "joint"):
            raise ValueError(
                f"action_type must be 'cartesian' or 'joint', got {self.action_type!r}"
            )
        for name in ("timesteps", "n_envs"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        self.update_schedule()  # ValueError for a ratio n_envs cannot give
        if self.bc_demos < 0:
            raise ValueError(f"bc_demos must be >= 0, got {self.bc_demos}")
        for name in self.objects or []:
            if name not in CATALOGUE:
                raise ValueError(f"unknown object {name!r}; catalogue: {', '.join(CATALOGUE)}")
        return self

    def update_schedule(self) -> tuple[int, int]:
        """SAC/TQC's ``(train_freq, gradient_steps)`` in vector steps that give
        ``updates_per_env_step`` updates per env step with ``n_envs`` envs."""
        per_vector_step = self.updates_per_env_step * self.n_envs
        if per_vector_step >= 1 and float(per_vector_step).is_integer():
            return 1, int(per_vector_step)
        if 0 < per_vector_step < 1 and float(1 / per_vector_step).is_integer():
            return int(1 / per_vector_step), 1
        raise ValueError(
            f"updates_per_env_step={self.updates_per_env_step} with n_envs={self.n_envs} is "
            f"{per_vector_step:g} updates per vector step; it must be a whole number of updates "
            "per vector step or one update every whole number of vector steps"
        )

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
        if self.pose == "manifold":
            return "manifold", {"models": self.pose_model}
        return "oracle", {}

    def to_json(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> TrainConfig:
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"unknown training settings {unknown}; valid: {sorted(known)}")
        return cls(**data).validate()


def make_policy_env(config: TrainConfig, objects: list[str] | None = None) -> gym.Env:
    """The env a policy of this run acts in (observations as in training, no residual)."""
    pose, kwargs = config.pose_args()
    return make_env(
        config.env_id,
        pose=pose,
        pose_kwargs=kwargs,
        classes=config.class_names(),
        objects=objects if objects is not None else config.objects,
    )


def make_training_env(config: TrainConfig) -> gym.Env:
    """One training env: the policy env, wrapped as a residual problem if asked."""
    env = make_policy_env(config)
    if config.residual:
        env = ResidualActionWrapper(env, scale=config.residual_scale)
    return env


def _monitored(config: TrainConfig) -> gym.Env:
    from stable_baselines3.common.monitor import Monitor

    return Monitor(make_training_env(config), info_keywords=("is_success",))


def make_vec_env(config: TrainConfig):
    """``n_envs`` training envs (``SubprocVecEnv``; ``DummyVecEnv`` for one), normalised."""
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecNormalize

    fns = [functools.partial(_monitored, config) for _ in range(config.n_envs)]
    venv = DummyVecEnv(fns) if config.n_envs == 1 else SubprocVecEnv(fns, start_method="spawn")
    if config.normalize:
        venv = VecNormalize(venv, norm_obs=True, norm_reward=False)
    return venv


def policy_meta(config: TrainConfig, env: gym.Env, timesteps: int) -> dict[str, Any]:
    """``policy.json``: how to rebuild the policy's inputs, and what it saw in training."""
    shapes = {k: list(s.shape) for k, s in env.observation_space.spaces.items()}
    residual = None
    if config.residual:
        attr = env.get_wrapper_attr
        residual = {
            "scale": config.residual_scale,
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
        "action_type": config.action_type,
        "classes": config.class_names(),
        "observation_shapes": shapes,
        "residual": residual,
        "trained_timesteps": int(timesteps),
        "saw_scripted_controller": {
            "residual_base": bool(config.residual),
            "bc_demo_episodes": int(config.bc_demos),
        },
        "config": config.to_json(),
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


def build_model(config: TrainConfig, venv, tb_dir: Path | None):
    from sb3_contrib import TQC
    from stable_baselines3 import PPO, SAC

    common = {
        "policy": "MultiInputPolicy",
        "env": venv,
        "learning_rate": config.learning_rate,
        "seed": config.seed,
        "verbose": 0,
        "device": "cpu",
        "tensorboard_log": str(tb_dir) if tb_dir else None,
    }
    if config.algo == "ppo":
        n_steps = max(8, config.n_steps // config.n_envs)
        kwargs = {"log_std_init": config.log_std_init} if config.residual else {}
        model = PPO(
            n_steps=n_steps,
            batch_size=min(64, n_steps * config.n_envs),
            policy_kwargs={"net_arch": list(config.net_arch), **kwargs},
            **common,
        )
    else:
        cls = SAC if config.algo == "sac" else TQC
        train_freq, gradient_steps = config.update_schedule()
        model = cls(
            buffer_size=config.buffer_size,
            batch_size=config.batch_size,
            learning_starts=config.learning_starts,
            train_freq=train_freq,
            gradient_steps=gradient_steps,
            ent_coef=f"auto_{config.ent_coef_init}",
            policy_kwargs={"net_arch": list(config.net_arch)},
            **common,
        )
    if config.residual:
        _zero_init_actor(model, config.log_std_init)
    return model


class _Run:
    """The pieces of one run and how they are saved."""

    def __init__(self, config: TrainConfig, out: Path, model, venv, state: dict) -> None:
        self.config, self.out, self.model, self.venv, self.state = config, out, model, venv, state
        self.clock = TrainingClock(state.get("wall_s", 0.0))
        self.eval_env = make_policy_env(config)
        self.meta_env = make_training_env(config)  # observation space incl. base_action

    def normalizer(self) -> ObservationNormalizer | None:
        return (
            ObservationNormalizer.from_vec_normalize(self.venv) if self.config.normalize else None
        )

    def policy(self, model) -> SB3Policy:
        return SB3Policy(
            model, policy_meta(self.config, self.meta_env, model.num_timesteps), self.normalizer()
        )

    def save(self, model) -> None:
        ck = self.out / "checkpoint"
        ck.mkdir(parents=True, exist_ok=True)
        atomic_save(ck / "model.zip", model.save)
        if hasattr(model, "replay_buffer") and model.replay_buffer is not None:
            atomic_save(ck / "replay_buffer.pkl", model.save_replay_buffer)
        if self.config.normalize:
            atomic_save(ck / "vecnormalize.pkl", self.venv.save)
        self.export(model, self.out / "policy")
        self.state.update(timesteps=int(model.num_timesteps), wall_s=round(self.clock.seconds, 2))
        atomic_write_json(ck / "state.json", self.state)

    def export(self, model, path: Path) -> None:
        path.mkdir(parents=True, exist_ok=True)
        atomic_save(path / "model.zip", model.save)
        meta = policy_meta(self.config, self.meta_env, model.num_timesteps)
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
    demos = collect_demonstrations(run.meta_env, c.bc_demos, seed=c.seed * 1000 + 500_000)
    if c.normalize:
        for k, v in demos.obs.items():
            run.venv.obs_rms[k].update(v)
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


def _limit_threads(n: int) -> None:
    """Torch's intra-op threads: on busy shared cores, several threads make the updates of
    small networks many times slower than one (see the README's learned-policy section)."""
    import torch as th

    if n > 0:
        th.set_num_threads(n)


def train(config: TrainConfig, out: str | Path) -> dict[str, Any]:
    """Train from scratch into ``out`` (which must not hold a run yet); returns the state."""
    config.validate()
    _limit_threads(config.torch_threads)
    out = Path(out)
    if (out / "config.json").exists():
        raise ValueError(f"{out} already holds a run; resume it with --resume {out}")
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out / "config.json", config.to_json())
    venv = make_vec_env(config)
    model = build_model(config, venv, out / "tb" if config.tensorboard else None)
    run = _Run(config, out, model, venv, {"timesteps": 0, "wall_s": 0.0, "eval": []})
    try:
        if config.bc_demos:
            run.state["demos"] = _seed_with_demos(run)
        run.learn(config.timesteps)
    finally:
        run.close()
    return run.state


def resume(out: str | Path, timesteps: int | None = None) -> dict[str, Any]:
    """Continue the run in ``out`` from its last checkpoint (to ``timesteps`` in total, default
    the configured number); returns the state."""
    from stable_baselines3.common.vec_env import VecNormalize

    out = Path(out)
    ck = out / "checkpoint"
    for p in (out / "config.json", ck / "model.zip", ck / "state.json"):
        if not p.is_file():
            raise FileNotFoundError(f"cannot resume {out}: {p.name} is missing (no checkpoint yet)")
    config = TrainConfig.from_json(json.loads((out / "config.json").read_text()))
    if timesteps is not None:
        config.timesteps = int(timesteps)
        atomic_write_json(out / "config.json", config.to_json())
    state = json.loads((ck / "state.json").read_text())
    _limit_threads(config.torch_threads)
    venv = make_vec_env(config)
    if config.normalize:
        venv = VecNormalize.load(str(ck / "vecnormalize.pkl"), venv.venv)
    from scorbot_gym.policies.sb3 import _algorithms

    tb = str(out / "tb") if config.tensorboard else None
    model = _algorithms()[config.algo].load(
        ck / "model.zip", env=venv, device="cpu", tensorboard_log=tb
    )
    if (ck / "replay_buffer.pkl").is_file() and hasattr(model, "replay_buffer"):
        model.load_replay_buffer(ck / "replay_buffer.pkl")
    model._last_obs = None  # the interrupted episode is not continued: start fresh episodes
    run = _Run(config, out, model, venv, state)
    try:
        run.learn(config.timesteps - model.num_timesteps)
    finally:
        run.close()
    return run.state


__all__ = [
    "ALGOS",
    "POSES",
    "TrainConfig",
    "build_model",
    "make_policy_env",
    "make_vec_env",
    "resume",
    "train",
]
