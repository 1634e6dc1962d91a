"""RL fine-tuning of a saved imitation policy, RLPD-style (Ball et al. 2023), on SB3's SAC.

The imitation policy (:mod:`scorbot_gym.policies.imitation`) is an MLP on normalised features
of the observation and of its own executed-action history, with 5 arm outputs squashed by tanh
and 1 gripper logit whose sign is the command. That is SAC's actor: ``latent_pi`` (the hidden
ReLU layers) and ``mu`` (the output layer) take the MLP's weights, and SAC's tanh squashing of
the mean gives the arm's tanh and keeps the gripper logit's sign. So:

- :class:`ImitationFeatures` gives the SB3 agent exactly the imitation policy's input (the
  features normalised with the policy's own statistics) and executes the gripper as the
  policy does (the sign of the command: the demonstrations' gripper is binary);
- :func:`init_actor` copies the MLP into the actor and starts ``log_std`` low, so the first
  episodes are the imitation policy's (deterministically, exactly its actions);
- :class:`DemoMixReplayBuffer` keeps the demonstrations in a replay buffer of their own and
  draws ``demo_ratio`` of every batch from it (RLPD's symmetric sampling at 0.5);
- :class:`RLPDSAC` is SAC whose first ``critic_warmup`` updates train the critic only (a
  randomly initialised critic's gradient would drag the actor away from the demonstrations
  before it has learned anything), with an optional behaviour-cloning term on the batch's
  demonstration rows (``bc_coef`` times the batch's mean ``|Q|``, as TD3+BC scales it, so the
  weight does not depend on the reward's scale);
- :func:`to_imitation_policy` writes the actor back as an imitation policy folder (numpy
  inference, no torch, a few hundred kB), which ``load_policy`` and ``rollout --policy`` load.

RLPD's other ingredients (critic ensembles with LayerNorm, many updates per env step) are left
out: on a shared 2-core CPU one update per env step is what a fine-tune can afford.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3 import SAC
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.type_aliases import ReplayBufferSamples
from stable_baselines3.common.utils import polyak_update
from torch.nn import functional as F

from scorbot_gym.policies.imitation import (
    FEATURE_CLIP,
    MLP,
    ActionHistory,
    ImitationPolicy,
)
from scorbot_gym.rl.imitation import LabelledEpisode


def executed_action(action: np.ndarray) -> np.ndarray:
    """What the env receives: the arm clipped to [-1, 1], the gripper +1 / -1 by its sign
    (as :func:`scorbot_gym.policies.imitation.to_action`)."""
    a = np.clip(np.asarray(action, np.float32), -1.0, 1.0)
    a[..., -1] = np.where(a[..., -1] > 0, 1.0, -1.0)
    return a


def load_init_policy(path: str | Path, action_type: str | None = None) -> ImitationPolicy:
    """The imitation policy a fine-tune starts from (``learned`` or a policy / run folder);
    anything else is a one-line error."""
    from scorbot_gym.policies.loading import load_policy

    policy = load_policy(path)
    if not isinstance(policy, ImitationPolicy):
        raise ValueError(
            f"--init-policy {path} is not an imitation policy (policy.json algo "
            f"{policy.meta.get('algo')!r}); fine-tuning starts from `learned` or a folder "
            "written by the imitation trainer or by an earlier fine-tune"
        )
    if action_type is not None and policy.meta["action_type"] != action_type:
        raise ValueError(
            f"--init-policy {path} outputs {policy.meta['action_type']} actions, the run "
            f"uses {action_type} (use --action-type {policy.meta['action_type']})"
        )
    return policy


class ImitationFeatures(gym.Wrapper):
    """The imitation policy's input as a flat observation: normalised features of the pose
    observation and of the executed-action history. Actions are executed as the imitation
    policy executes them (:func:`executed_action`). Reads observations only."""

    def __init__(self, env: gym.Env, policy: ImitationPolicy) -> None:
        super().__init__(env)
        self.features = ImitationPolicy(policy.net, policy.mean, policy.std, policy.meta)
        self.features.bind(env)
        self.history = ActionHistory(policy.history_spec)
        n = len(policy.mean)
        self.observation_space = gym.spaces.Box(-FEATURE_CLIP, FEATURE_CLIP, (n,), np.float32)

    def _observe(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        self._last_obs = obs  # the history takes it with the action chosen on it
        return self.features.normalise(self.features.features(obs, self.history))

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        self.history.reset()
        return self._observe(obs), info

    def step(self, action):
        action = executed_action(action)
        self.features.remember(self.history, action, self._last_obs)
        obs, reward, terminated, truncated, info = self.env.step(action)
        return self._observe(obs), reward, terminated, truncated, info


def init_actor(model: SAC, policy: ImitationPolicy, log_std_init: float) -> None:
    """Copy the imitation MLP into ``model``'s actor (``latent_pi`` + ``mu``); ``log_std``
    starts at ``log_std_init`` everywhere. The actor's deterministic action is then the
    imitation policy's (arm: tanh of the same outputs; gripper: same sign)."""
    actor = model.actor
    linears = [m for m in actor.latent_pi if isinstance(m, th.nn.Linear)] + [actor.mu]
    weights, biases = policy.net.weights, policy.net.biases
    shapes = [tuple(lin.weight.shape[::-1]) for lin in linears]
    if shapes != [w.shape for w in weights]:
        raise ValueError(
            f"the actor's layers {shapes} differ from the initial policy's "
            f"{[w.shape for w in weights]} (net_arch must be its hidden layers "
            f"{policy.meta['network']['hidden']})"
        )
    with th.no_grad():
        for lin, w, b in zip(linears, weights, biases, strict=True):
            lin.weight.copy_(th.as_tensor(np.asarray(w).T))
            lin.bias.copy_(th.as_tensor(np.asarray(b)))
        actor.log_std.weight.zero_()
        actor.log_std.bias.fill_(log_std_init)


def actor_network(model: SAC) -> MLP:
    """The actor's mean network as the imitation policy's numpy MLP (pre-tanh outputs)."""
    actor = model.actor
    linears = [m for m in actor.latent_pi if isinstance(m, th.nn.Linear)] + [actor.mu]
    return MLP(
        [lin.weight.detach().cpu().numpy().T.copy() for lin in linears],
        [lin.bias.detach().cpu().numpy().copy() for lin in linears],
    )


def to_imitation_policy(
    model: SAC,
    init: ImitationPolicy,
    record: dict[str, Any],
    provenance: dict[str, Any] | None = None,
) -> ImitationPolicy:
    """The fine-tuned actor as a stand-alone imitation-format policy. Its ``policy.json``
    keeps the initial policy's description and training record, and adds ``rl_finetune``
    (``record``); ``training`` sums demonstrations, env steps and wall time of both stages.
    It says ``"trained_by": "rl_finetune"``, with the fine-tune's ``provenance`` (the initial
    policy's own is in its ``data.init_policy``)."""
    meta = copy.deepcopy(init.meta)
    meta.pop("normalization", None)  # written again by save()
    meta["trained_by"] = "rl_finetune"
    meta["provenance"] = provenance if provenance is not None else "not recorded"
    before = init.meta.get("training") or {}
    base = before.get("imitation", before)  # a fine-tune of a fine-tune keeps the first record
    first = before.get("rl_finetune_history", []) + (
        [before["rl_finetune"]] if "rl_finetune" in before else []
    )
    demos = int(base.get("demonstration_episodes", 0)) + sum(
        int(r.get("demonstration_episodes", 0)) for r in [*first, record]
    )
    env_steps = int(base.get("env_steps", 0)) + sum(
        int(r.get("env_steps", 0)) for r in [*first, record]
    )
    wall = float(base.get("wall_time_s", 0.0)) + sum(
        float(r.get("wall_time_s", 0.0)) for r in [*first, record]
    )
    meta["training"] = {
        "method": "behaviour cloning + DAgger, then RLPD-style SAC fine-tuning",
        "demonstration_episodes": demos,
        "dagger_episodes": base.get("dagger_episodes"),
        "env_steps": env_steps,
        "wall_time_s": wall,
        "imitation": base,
        "rl_finetune": record,
        **({"rl_finetune_history": first} if first else {}),
    }
    saw = dict(meta.get("saw_scripted_controller") or {})
    saw["bc_demo_episodes"] = demos
    saw["residual_base"] = False
    meta["saw_scripted_controller"] = saw
    meta["uses_scripted_controller"] = False
    return ImitationPolicy(actor_network(model), init.mean, init.std, meta)


# --- demonstrations in the batch -----------------------------------------------------------


def demo_transitions(
    episodes: Sequence[LabelledEpisode], policy: ImitationPolicy
) -> dict[str, np.ndarray]:
    """The episodes' transitions in the fine-tune's observation (features with the executed-
    action history, normalised by ``policy``); ``done`` only on termination (a time limit is
    bootstrapped through, as SB3 does for online data)."""
    obs, next_obs, actions, rewards, dones = [], [], [], [], []
    history = ActionHistory(policy.history_spec)
    keys = None
    for ep in episodes:
        keys = list(ep.observations)
        history.reset()
        feats = []
        for t in range(len(ep) + 1):
            o = {k: ep.observations[k][t] for k in keys}
            feats.append(policy.normalise(policy.features(o, history)))
            if t < len(ep):
                policy.remember(history, executed_action(ep.actions[t]), o)
        feats = np.stack(feats)
        obs.append(feats[:-1])
        next_obs.append(feats[1:])
        actions.append(executed_action(ep.actions))
        rewards.append(np.asarray(ep.rewards, np.float32))
        dones.append(np.asarray(ep.terminations, np.float32))
    return {
        "observations": np.concatenate(obs),
        "next_observations": np.concatenate(next_obs),
        "actions": np.concatenate(actions),
        "rewards": np.concatenate(rewards),
        "dones": np.concatenate(dones),
    }


def demo_buffer(transitions: dict[str, np.ndarray], model: SAC) -> ReplayBuffer:
    """A replay buffer of its own holding exactly the demonstration transitions."""
    n = len(transitions["actions"])
    buf = ReplayBuffer(
        max(n, 1),
        model.observation_space,
        model.action_space,
        device=model.device,  # its samples join the online buffer's batches (th.cat)
        n_envs=1,
        handle_timeout_termination=False,
    )
    buf.observations[:n, 0] = transitions["observations"]
    buf.next_observations[:n, 0] = transitions["next_observations"]
    buf.actions[:n, 0] = transitions["actions"]
    buf.rewards[:n, 0] = transitions["rewards"]
    buf.dones[:n, 0] = transitions["dones"]
    buf.pos, buf.full = n % buf.buffer_size, n == buf.buffer_size
    return buf


class DemoMixReplayBuffer(ReplayBuffer):
    """The online replay buffer, plus ``demos`` (set after construction): each batch has
    ``round(demo_ratio * batch_size)`` demonstration rows first, then online rows (all demos
    while the online buffer is empty). ``last_demo_rows`` tells the trainer which rows are
    demonstrations (for the behaviour-cloning term); ``demo_rows_drawn`` counts them all."""

    def __init__(self, *args, demo_ratio: float = 0.5, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.demo_ratio = float(demo_ratio)
        self.demos: ReplayBuffer | None = None
        self.last_demo_rows = 0
        self.demo_rows_drawn = 0

    def sample(self, batch_size: int, env=None) -> ReplayBufferSamples:
        has_demos = self.demos is not None and self.demos.size() > 0
        online = self.size() > 0
        n_demo = round(self.demo_ratio * batch_size) if has_demos else 0
        if not online:
            n_demo = batch_size
        parts = []
        if n_demo:
            parts.append(self.demos.sample(n_demo, env=env))
        if batch_size - n_demo:
            parts.append(super().sample(batch_size - n_demo, env=env))
        self.last_demo_rows = n_demo
        self.demo_rows_drawn += n_demo
        if len(parts) == 1:
            return parts[0]
        return ReplayBufferSamples(
            *(th.cat([getattr(p, f) for p in parts]) for f in ReplayBufferSamples._fields[:5])
        )


class RLPDSAC(SAC):
    """SAC with the critic warm-up and the optional behaviour-cloning term of the module
    docstring (``critic_warmup`` updates; ``bc_coef``), and an actor step size of its own
    (``actor_learning_rate``; default: SAC's ``learning_rate``). Otherwise SB3's SAC update."""

    def __init__(
        self,
        *args,
        critic_warmup: int = 0,
        bc_coef: float = 0.0,
        actor_learning_rate: float | None = None,
        **kwargs,
    ) -> None:
        self.critic_warmup, self.bc_coef = int(critic_warmup), float(bc_coef)
        self.actor_learning_rate = actor_learning_rate
        super().__init__(*args, **kwargs)

    def _bc_loss(self, obs: th.Tensor, actions: th.Tensor) -> th.Tensor:
        """The imitation loss on demonstration rows: MSE on the arm's tanh outputs, binary
        cross-entropy on the gripper logit (what the imitation policy was trained with)."""
        mean, _, _ = self.actor.get_action_dist_params(obs)
        arm = F.mse_loss(th.tanh(mean[:, :-1]), actions[:, :-1])
        grip = F.binary_cross_entropy_with_logits(mean[:, -1], (actions[:, -1] > 0).float())
        return arm + grip

    def train(self, gradient_steps: int, batch_size: int = 64) -> None:
        self.policy.set_training_mode(True)
        optimizers = [self.actor.optimizer, self.critic.optimizer]
        if self.ent_coef_optimizer is not None:
            optimizers += [self.ent_coef_optimizer]
        self._update_learning_rate(optimizers)
        if self.actor_learning_rate is not None:  # Adam moves every weight by ~lr per step
            for group in self.actor.optimizer.param_groups:  # whatever the loss's scale: the
                group["lr"] = self.actor_learning_rate  # actor needs a smaller step than the critic
        ent_coef_losses, ent_coefs, actor_losses, critic_losses, bc_losses = [], [], [], [], []

        for gradient_step in range(gradient_steps):
            replay_data = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)
            n_demo = getattr(self.replay_buffer, "last_demo_rows", 0)
            actor_moves = self._n_updates + gradient_step >= self.critic_warmup
            discounts = replay_data.discounts if replay_data.discounts is not None else self.gamma
            actions_pi, log_prob = self.actor.action_log_prob(replay_data.observations)
            log_prob = log_prob.reshape(-1, 1)

            ent_coef_loss = None
            if self.ent_coef_optimizer is not None and self.log_ent_coef is not None:
                ent_coef = th.exp(self.log_ent_coef.detach())
                ent_coef_loss = -(
                    self.log_ent_coef * (log_prob + self.target_entropy).detach()
                ).mean()
                ent_coef_losses.append(ent_coef_loss.item())
            else:
                ent_coef = self.ent_coef_tensor
            ent_coefs.append(ent_coef.item())
            if ent_coef_loss is not None and actor_moves:
                self.ent_coef_optimizer.zero_grad()
                ent_coef_loss.backward()
                self.ent_coef_optimizer.step()

            with th.no_grad():
                next_actions, next_log_prob = self.actor.action_log_prob(
                    replay_data.next_observations
                )
                next_q = th.cat(
                    self.critic_target(replay_data.next_observations, next_actions), dim=1
                )
                next_q, _ = th.min(next_q, dim=1, keepdim=True)
                next_q = next_q - ent_coef * next_log_prob.reshape(-1, 1)
                target_q = replay_data.rewards + (1 - replay_data.dones) * discounts * next_q
            current_q = self.critic(replay_data.observations, replay_data.actions)
            critic_loss = 0.5 * sum(F.mse_loss(q, target_q) for q in current_q)
            critic_losses.append(critic_loss.item())
            self.critic.optimizer.zero_grad()
            critic_loss.backward()
            self.critic.optimizer.step()

            if actor_moves:
                q_pi = th.cat(self.critic(replay_data.observations, actions_pi), dim=1)
                min_q_pi, _ = th.min(q_pi, dim=1, keepdim=True)
                actor_loss = (ent_coef * log_prob - min_q_pi).mean()
                if self.bc_coef > 0 and n_demo > 0:
                    bc = self._bc_loss(
                        replay_data.observations[:n_demo], replay_data.actions[:n_demo]
                    )
                    bc_losses.append(bc.item())
                    actor_loss = actor_loss + self.bc_coef * min_q_pi.abs().mean().detach() * bc
                actor_losses.append(actor_loss.item())
                self.actor.optimizer.zero_grad()
                actor_loss.backward()
                self.actor.optimizer.step()

            if gradient_step % self.target_update_interval == 0:
                polyak_update(self.critic.parameters(), self.critic_target.parameters(), self.tau)
                polyak_update(self.batch_norm_stats, self.batch_norm_stats_target, 1.0)

        self._n_updates += gradient_steps
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        self.logger.record("train/ent_coef", np.mean(ent_coefs))
        self.logger.record("train/critic_loss", np.mean(critic_losses))
        self.logger.record("train/actor_frozen", float(not actor_losses))
        if actor_losses:
            self.logger.record("train/actor_loss", np.mean(actor_losses))
        if bc_losses:
            self.logger.record("train/bc_loss", np.mean(bc_losses))
        if ent_coef_losses:
            self.logger.record("train/ent_coef_loss", np.mean(ent_coef_losses))


__all__ = [
    "DemoMixReplayBuffer",
    "ImitationFeatures",
    "RLPDSAC",
    "actor_network",
    "demo_buffer",
    "demo_transitions",
    "executed_action",
    "init_actor",
    "load_init_policy",
    "to_imitation_policy",
]
