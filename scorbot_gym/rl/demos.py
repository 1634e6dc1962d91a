"""Scripted demonstrations: collection, replay-buffer seeding and behaviour cloning.

Used by ``scorbot-gym train --bc-demos N``: N episodes of the scripted controller on the
training env are (1) added to an off-policy algorithm's replay buffer and (2) used to pre-train
the actor by behaviour cloning (mean-squared error of the deterministic action for SAC/TQC,
negative log-likelihood for PPO) before any online step. On a residual env the demonstrator is
the residual that leaves the scripted action unchanged (zero).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import gymnasium as gym
import numpy as np

from scorbot_gym.policies.base import Policy
from scorbot_gym.policies.scripted import ScriptedGraspPolicy
from scorbot_gym.rl.residual import ResidualActionWrapper


class ZeroResidual:
    """The demonstrator on a residual env: keep the base action."""

    def __init__(self, action_dim: int) -> None:
        self.action_dim = action_dim

    def reset(self, obs, info) -> None:
        pass

    def act(self, obs) -> np.ndarray:
        return np.zeros(self.action_dim, np.float32)


@dataclass
class Demonstrations:
    """Transitions of scripted episodes (arrays stacked over all steps of all episodes)."""

    obs: dict[str, np.ndarray]
    next_obs: dict[str, np.ndarray]
    actions: np.ndarray
    rewards: np.ndarray
    dones: np.ndarray  # terminated (not truncated): the bootstrap target stops here
    episode_success: np.ndarray  # per transition: whether its episode succeeded

    def __len__(self) -> int:
        return len(self.actions)

    @property
    def success_rate(self) -> float:
        return float(np.mean(self.episode_success)) if len(self) else 0.0


def demonstrator_for(env: gym.Env) -> Policy:
    """The scripted controller, or the zero residual on a :class:`ResidualActionWrapper`."""
    inner = env
    while isinstance(inner, gym.Wrapper):
        if isinstance(inner, ResidualActionWrapper):
            return ZeroResidual(env.action_space.shape[0])
        inner = inner.env
    return ScriptedGraspPolicy.for_env(env)


def collect_demonstrations(
    env: gym.Env, episodes: int, seed: int, policy: Policy | None = None
) -> Demonstrations:
    """Run ``episodes`` seeded episodes (seeds ``seed, seed + 1, ...``) and keep every step."""
    if episodes < 1:
        raise ValueError(f"demonstration episodes must be >= 1, got {episodes}")
    policy = policy or demonstrator_for(env)
    obs_l, next_l, act_l, rew_l, done_l, succ_l = [], [], [], [], [], []
    for ep in range(episodes):
        obs, info = env.reset(seed=seed + ep)
        policy.reset(obs, info)
        start = len(act_l)
        while True:
            action = np.asarray(policy.act(obs), np.float32)
            nxt, reward, terminated, truncated, info = env.step(action)
            obs_l.append(obs)
            next_l.append(nxt)
            act_l.append(action)
            rew_l.append(reward)
            done_l.append(terminated)
            obs = nxt
            if terminated or truncated:
                break
        succ_l += [bool(info["is_success"])] * (len(act_l) - start)

    def stack(rows: list[dict]) -> dict[str, np.ndarray]:
        return {k: np.stack([r[k] for r in rows]) for k in rows[0]}

    return Demonstrations(
        stack(obs_l),
        stack(next_l),
        np.stack(act_l),
        np.asarray(rew_l, np.float32),
        np.asarray(done_l, bool),
        np.asarray(succ_l, bool),
    )


def add_to_replay_buffer(model, demos: Demonstrations) -> int:
    """Add the transitions to an off-policy model's buffer, ``n_envs`` at a time (the buffer's
    layout); returns how many were added (a remainder below ``n_envs`` is dropped)."""
    buf = model.replay_buffer
    n_envs = buf.n_envs
    added = 0
    for i in range(0, len(demos) - n_envs + 1, n_envs):
        sl = slice(i, i + n_envs)
        buf.add(
            {k: v[sl] for k, v in demos.obs.items()},
            {k: v[sl] for k, v in demos.next_obs.items()},
            demos.actions[sl],
            demos.rewards[sl],
            demos.dones[sl],
            [{} for _ in range(n_envs)],
        )
        added += n_envs
    return added


def behaviour_clone(
    model,
    demos: Demonstrations,
    normalize: Callable[[dict[str, np.ndarray]], dict[str, np.ndarray]] | None,
    steps: int = 2000,
    batch_size: int = 256,
    learning_rate: float = 1e-3,
    seed: int = 0,
) -> list[float]:
    """Pre-train the model's actor on the successful episodes' actions; returns the losses."""
    import torch as th

    keep = demos.episode_success if demos.episode_success.any() else np.ones(len(demos), bool)
    obs = {k: v[keep] for k, v in demos.obs.items()}
    if normalize is not None:
        obs = normalize(obs)
    actions = np.clip(demos.actions[keep], -0.999, 0.999)
    rng = np.random.default_rng(seed)
    policy = model.policy
    on_policy = hasattr(policy, "evaluate_actions")
    params = policy.parameters() if on_policy else policy.actor.parameters()
    opt = th.optim.Adam(params, lr=learning_rate)
    losses = []
    policy.set_training_mode(True)
    for _ in range(steps):
        idx = rng.integers(0, len(actions), batch_size)
        obs_t, _ = policy.obs_to_tensor({k: v[idx] for k, v in obs.items()})
        act_t = th.as_tensor(actions[idx], device=policy.device)
        if on_policy:
            _, log_prob, _ = policy.evaluate_actions(obs_t, act_t)
            loss = -log_prob.mean()
        else:
            loss = th.nn.functional.mse_loss(policy.actor(obs_t, deterministic=True), act_t)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(float(loss.item()))
    policy.set_training_mode(False)
    return losses
