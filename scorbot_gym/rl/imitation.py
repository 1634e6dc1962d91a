"""Imitation learning of a stand-alone grasping policy: behaviour cloning from scripted
demonstrations with DART noise, then DAgger.

- **Demonstrations** (:func:`collect_episodes` with ``learner=None``): the scripted controller
  acts; with DART (Laskey et al. 2017) Gaussian noise of std ``dart_sigma`` is added to the
  executed arm action while the *label* stays the controller's clean action, so the data
  already contains small recoveries. Each step stores the observation, the executed action
  and the label.
- **DAgger** (Ross et al. 2011): round ``i`` runs the current learner, mixed per step with the
  expert at probability ``beta_i = beta * beta_decay**i``; the scripted controller, given the
  *oracle* pose (:func:`oracle_view`, from ``info["object_pose"]``), labels every visited
  state; the union of all data trains the next policy.

**Estimation error** (``ImitationConfig.poses``): the learner's observation may come from a
noisy or an estimated pose while the expert still labels from the oracle pose, so the learner
is taught the right action for the *true* state in the states its *estimate* leads it into
(what DAgger with privileged labels does; "asymmetric" imitation). Episode ``i`` (of the
demonstrations and of every DAgger round) runs under ``poses[i % len(poses)]``: e.g.
``("oracle", "noisy@0:20", "noisy@0.02:0", "manifold")``. Its features already hold
``pose_valid``, ``pose_confidence`` and ``pose_age``: trained on the oracle alone they never
vary and the policy ignores them (a stale estimate held while the gripper hides the object
then looks like an object left behind); trained on estimates it can learn when to trust them.
Measured (``benchmarks/results/compare.json``, config ``noise_augmented``): per-step independent
noise (``noisy@...``) does *not* teach this policy robustness. It sees one estimate and no
history of estimates, so under such noise the oracle labels are not a function of its input; the
fit averages them, the learner drifts, and short DAgger fine-tunes of the shipped policy fell to
14-16 % (the same recipe on the oracle: 90-92 %). Noise that persists, as an estimator's does,
or a pose history in the features are what such training needs: ``HistorySpec.pose_window``
gives the policy the summary of its last fresh estimates
(:meth:`~scorbot_gym.policies.imitation.ActionHistory.pose_features`).

The expert is stateful (its phase and waypoint evolve with the states the learner visits); the
learner is not given any of that state: its features are the observation plus its own
executed-action history (:mod:`scorbot_gym.policies.imitation`).

The data are :class:`LabelledEpisode` objects, which :mod:`scorbot_gym.rl.datasets` writes to
and reads from Minari datasets (``scorbot-gym demos``), so :func:`train_imitation` can start
from a recorded dataset.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np

from scorbot_gym import seeds as seed_ranges
from scorbot_gym.envs.factory import make_env
from scorbot_gym.objects import CATALOGUE
from scorbot_gym.policies.imitation import (
    AGE_FEATURE,
    ALGO,
    MLP,
    OBSERVATION_KEYS,
    ActionHistory,
    HistorySpec,
    ImitationPolicy,
    n_features,
    to_action,
)
from scorbot_gym.policies.object_features import check_object_features
from scorbot_gym.policies.sb3 import FORMAT, VERSION
from scorbot_gym.policies.scripted import ScriptedGraspPolicy
from scorbot_gym.tasks.grasp import FAILURE_CAUSES


@dataclass
class LabelledEpisode:
    """One episode: ``T + 1`` observations, ``T`` executed actions, ``T + 1`` expert labels
    (the label of the last observation is recorded too), rewards, flags and flat infos."""

    seed: int
    observations: dict[str, np.ndarray]
    actions: np.ndarray
    labels: np.ndarray
    rewards: np.ndarray
    terminations: np.ndarray
    truncations: np.ndarray
    infos: dict[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.actions)

    @property
    def success(self) -> bool:
        return bool(self.infos["is_success"][-1])


@dataclass
class DemonstrationSet:
    """Recorded demonstrations with what they were recorded with (``settings``: the dataset's
    id and file hash, action type, pose source, seeds, DART sigma; see
    :func:`scorbot_gym.rl.datasets.read_dataset`). :func:`train_imitation` checks the action
    type against the env's and records these settings instead of its config's defaults."""

    episodes: list[LabelledEpisode]
    settings: dict[str, Any]

    def __len__(self) -> int:
        return len(self.episodes)

    def __iter__(self):
        return iter(self.episodes)


def oracle_view(obs: dict[str, np.ndarray], info: dict[str, Any], classes: Sequence[str]) -> dict:
    """The observation with the true pose and class (from ``info``) in place of the estimate:
    what the expert labels with, whatever pose source the learner sees."""
    out = dict(obs)
    out["object_pos"] = np.asarray(info["object_pose"]["position"], float)
    out["object_quat"] = np.asarray(info["object_pose"]["quaternion"], float)
    out["pose_valid"], out["pose_age"] = np.ones(1), np.zeros(1)
    out["pose_confidence"] = np.ones(1)
    onehot = np.zeros(len(classes))
    if info["object_name"] in classes:
        onehot[list(classes).index(info["object_name"])] = 1.0
    out["object_class"] = onehot
    return out


def flat_info(info: dict[str, Any], classes: Sequence[str]) -> dict:
    """The numeric facts of one ``info`` with the same keys at every step (what Minari stores):
    outcome, true pose and class, reward terms, the estimator's record (NaN where it has
    none); the caller adds the cameras' calibration."""
    perc = info.get("perception") or {}

    def num(key: str) -> float:
        v = perc.get(key)
        return float(v) if v is not None else float("nan")

    cause = info.get("failure_cause")
    out: dict[str, Any] = {
        "is_success": np.int8(bool(info.get("is_success", False))),
        "grasped": np.int8(bool(info.get("grasped", False))),
        "held_time": float(info.get("held_time", 0.0)),
        "failure_cause": np.int8(FAILURE_CAUSES.index(cause) if cause in FAILURE_CAUSES else -1),
        "object_position": np.asarray(info["object_pose"]["position"], float),
        "object_quaternion": np.asarray(info["object_pose"]["quaternion"], float),
        "object_class": np.int16(
            list(classes).index(info["object_name"]) if info["object_name"] in classes else -1
        ),
        "perception_valid": np.int8(bool(perc.get("valid", False))),
        "perception_rot_err_deg": num("rot_err_deg"),
        "perception_pos_err_cm": num("pos_err_cm"),
        "perception_add_s_cm": num("add_s_cm"),
        "perception_n_keypoints": np.int32(perc.get("n_keypoints", 0)),
        "perception_n_inliers": np.int32(perc.get("n_inliers", 0)),
        "perception_total_ms": num("total_ms"),
    }
    for k in ("reach", "grasp", "lift", "success"):
        out[f"reward_{k}"] = float(info.get(f"reward_{k}", 0.0))
    return out


class ExecutedActionExpert:
    """The scripted controller as a DAgger labeller that knows what was executed.

    The controller lifts a fixed time after it *commands* the fingers closed. When the learner
    drives, the controller's phase would run on although the fingers were never closed (its
    timer, not the gripper, moves it on), and it would label "lift" in a state where the
    learner's own gripper history says "not closed yet". After every executed action that
    opens the gripper while the controller is closing, lifting or holding, the controller goes
    back to its descent (where it re-plans from the pose, re-aligns and closes again): labels
    consistent with the history the learner sees. In demonstrations (the controller acts) the
    executed gripper is its own and nothing changes.

    ``keeps_close``: a decision to close stands until the learner closes. The controller
    closes when its descent reaches the grasp *or after 2 s of descent*, whatever the fingers
    touch. A learner whose descent is blocked (on the rim of an object a few millimetres off
    its estimate) and keeps the fingers open would otherwise send the controller back to a
    fresh 2 s descent: one "close" label per 2 s, all the others "keep descending, open",
    which teaches the learner to wait at the rim until the time limit. With it, the
    controller stays in its closing phase (its closing timer restarted, since the fingers
    have not begun to close), so every step of a blocked descent past the controller's
    timeout is labelled "close". Lifting and holding still go back to the descent.
    """

    def __init__(self, base: ScriptedGraspPolicy, keeps_close: bool = False) -> None:
        self.base = base
        self.keeps_close = keeps_close

    def reset(self, obs: dict[str, np.ndarray], info: dict[str, Any]) -> None:
        self.base.reset(obs, info)

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        return self.base.act(obs)

    def executed(self, action: np.ndarray) -> None:
        b = self.base
        if action[-1] <= 0:
            return
        if b.phase == "close" and self.keeps_close:
            b._phase_time = 0.0
        elif b.phase in ("close", "lift", "hold"):
            b.phase, b._phase_time = "descend", 0.0

    @classmethod
    def for_env(cls, env: gym.Env, keeps_close: bool = False) -> ExecutedActionExpert:
        return cls(ScriptedGraspPolicy.for_env(env), keeps_close=keeps_close)


def check_expert_options(sync_expert: bool, expert_keeps_close: bool) -> None:
    """One-line error for a labeller option that needs the executed-action expert."""
    if expert_keeps_close and not sync_expert:
        raise ValueError("expert_keeps_close needs sync_expert (the executed-action expert)")


def collect_episodes(
    env: gym.Env,
    seeds: Sequence[int],
    *,
    learner: ImitationPolicy | None = None,
    beta: float = 1.0,
    dart_sigma: float = 0.0,
    rng: np.random.Generator | None = None,
    expert_factory: Callable[[gym.Env], Any] | None = None,
    sync_expert: bool = False,
    expert_keeps_close: bool = False,
    keep: Callable[[dict[str, np.ndarray]], dict[str, np.ndarray]] | None = None,
) -> list[LabelledEpisode]:
    """Run one episode per seed; the expert labels every observation.

    Who acts: with ``learner=None`` the expert (plus DART noise ``dart_sigma`` on the arm);
    otherwise, at each step, the expert with probability ``beta`` and the learner otherwise.
    The learner's features use the history of *executed* actions. ``sync_expert`` makes the
    expert an :class:`ExecutedActionExpert` (the default expert: the scripted controller),
    ``expert_keeps_close`` its ``keeps_close``.
    ``keep`` maps each observation to what the episode stores (default: all of it), e.g. a
    pixel policy's small frames instead of the rendered images, to keep memory bounded.
    """
    rng = rng if rng is not None else np.random.default_rng(0)
    classes = tuple(env.get_wrapper_attr("class_names"))
    check_expert_options(sync_expert, expert_keeps_close)

    def default(env: gym.Env) -> Any:
        if sync_expert:
            return ExecutedActionExpert.for_env(env, keeps_close=expert_keeps_close)
        return ScriptedGraspPolicy.for_env(env)

    make_expert = expert_factory or default
    expert = make_expert(env)
    history = new_history(learner) if learner is not None else None
    episodes = []
    for seed in seeds:
        obs, info = env.reset(seed=int(seed))
        calibration = _calibration(info)
        expert.reset(oracle_view(obs, info, classes), info)
        if history is not None:
            history.reset()
        store = keep or (lambda o: o)
        rows, infos = [store(obs)], [info]
        actions, labels, rewards, terms, truncs = [], [], [], [], []
        while True:
            label = np.asarray(expert.act(oracle_view(obs, info, classes)), np.float32)
            labels.append(label)
            if learner is None or rng.random() < beta:
                action = label.copy()
                if dart_sigma > 0:
                    action[:-1] += rng.normal(0.0, dart_sigma, len(action) - 1)
                action = np.clip(action, -1.0, 1.0).astype(np.float32)
            else:
                action = learner.action_from_features(learner.features(obs, history))
            if history is not None:
                learner.remember(history, action, obs)
            if hasattr(expert, "executed"):
                expert.executed(action)
            obs, reward, terminated, truncated, info = env.step(action)
            rows.append(store(obs))
            infos.append(info)
            actions.append(action)
            rewards.append(reward)
            terms.append(terminated)
            truncs.append(truncated)
            if terminated or truncated:
                break
        labels.append(np.asarray(expert.act(oracle_view(obs, info, classes)), np.float32))
        flat = [{**flat_info(i, classes), **calibration} for i in infos]
        episodes.append(
            LabelledEpisode(
                seed=int(seed),
                observations={k: np.stack([r[k] for r in rows]) for k in rows[0]},
                actions=np.stack(actions),
                labels=np.stack(labels),
                rewards=np.asarray(rewards, np.float64),
                terminations=np.asarray(terms, bool),
                truncations=np.asarray(truncs, bool),
                infos={k: np.stack([f[k] for f in flat]) for k in flat[0]},
            )
        )
    return episodes


def new_history(learner: Any) -> ActionHistory:
    """The learner's per-episode memory: its own ``new_history()`` where it keeps more than
    actions (a pixel policy's recent frames), else an :class:`ActionHistory` of its spec."""
    make = getattr(learner, "new_history", None)
    return make() if make is not None else ActionHistory(learner.history_spec)


def _calibration(info: dict[str, Any]) -> dict[str, np.ndarray]:
    """The fixed cameras' calibration from the reset's info (repeated at every step)."""
    out = {}
    for cam, params in info.get("camera_params", {}).items():
        out[f"camera_{cam}_K"] = np.asarray(params["K"], float)
        out[f"camera_{cam}_world_from_camera"] = np.asarray(params["world_from_camera"], float)
        out[f"camera_{cam}_size"] = np.array([params["width"], params["height"]], np.int32)
    return out


# --- training ------------------------------------------------------------------------------


def episode_features(
    episode: LabelledEpisode, policy_like: ImitationPolicy
) -> tuple[np.ndarray, np.ndarray]:
    """Features (with the executed-action history) and labels of an episode's acted steps."""
    history = new_history(policy_like)
    keys = list(episode.observations)
    feats = []
    for t in range(len(episode)):
        obs = {k: episode.observations[k][t] for k in keys}
        feats.append(policy_like.features(obs, history))
        policy_like.remember(history, episode.actions[t], obs)
    return np.stack(feats), episode.labels[: len(episode)]


@dataclass
class ImitationConfig:
    """Everything that defines an imitation run (recorded in ``policy.json``)."""

    demos: int = 150
    dart_sigma: float = 0.2
    dagger_rounds: int = 4
    dagger_episodes: int = 60
    beta: float = 0.5
    beta_decay: float = 0.5
    hidden: tuple[int, ...] = (256, 256)
    fit_steps: int = 6000
    batch_size: int = 512
    learning_rate: float = 1e-3
    weight_decay: float = 1e-5
    history: HistorySpec = field(default_factory=HistorySpec)
    seed: int = 0
    torch_threads: int = 1
    sync_expert: bool = True
    #: the synchronised expert's decision to close stands until the learner closes
    #: (:class:`ExecutedActionExpert` ``keeps_close``); runs recorded before it had False
    expert_keeps_close: bool = False
    #: pose conditions the learner observes, round-robin over episodes (module docstring;
    #: :func:`learner_pose`); the expert labels from the oracle pose under every one
    poses: tuple[str, ...] = ("oracle",)
    #: what the network is told of the object besides its pose: ``"class"`` (a one-hot over
    #: the training catalogue) or ``"grasp_frame"`` (derived from any object's mesh;
    #: :mod:`scorbot_gym.policies.object_features`)
    object_features: str = "class"
    #: the objects the training episodes draw from (registered names); ``None``: the catalogue
    objects: tuple[str, ...] | None = None
    #: a saved imitation policy folder (or ``"learned"``: the shipped one) whose network the
    #: first fit starts from: fine-tuning it on these episodes (e.g. on estimated poses)
    #: instead of training from scratch; ``None``: from scratch
    init_policy: str | None = None

    def __post_init__(self) -> None:
        if isinstance(self.history, dict):
            self.history = HistorySpec.from_record(self.history)
        if isinstance(self.poses, str) or not self.poses:
            raise ValueError(f"poses must be a non-empty list of pose names, got {self.poses!r}")
        self.poses = tuple(self.poses)
        for name in self.poses:
            learner_pose(name)  # a bad name fails here, before any episode
        for name in ("demos", "fit_steps", "batch_size", "torch_threads"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        for name in ("dagger_rounds", "dagger_episodes"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        seed_ranges.check_run_seed(self.seed)
        seed_ranges.DEMONSTRATIONS.block(self.seed, self.demos)  # one-line error if too many
        seed_ranges.DAGGER.block(self.seed, self.dagger_rounds * self.dagger_episodes)
        if not 0.0 <= self.beta <= 1.0 or not 0.0 <= self.beta_decay <= 1.0:
            raise ValueError(
                f"beta and beta_decay must be in [0, 1], got {self.beta}, {self.beta_decay}"
            )
        if self.dart_sigma < 0:
            raise ValueError(f"dart_sigma must be >= 0, got {self.dart_sigma}")
        check_expert_options(self.sync_expert, self.expert_keeps_close)
        check_object_features(self.object_features)
        if self.objects is not None:
            if isinstance(self.objects, str) or not self.objects:
                raise ValueError(f"objects must be a non-empty list of names, got {self.objects!r}")
            self.objects = tuple(self.objects)
            unknown = [n for n in self.objects if n not in CATALOGUE]
            if unknown:
                raise ValueError(
                    f"unknown objects {unknown}; valid: {', '.join(CATALOGUE)} (register or "
                    "install others first)"
                )
        self.hidden = tuple(int(h) for h in self.hidden)


def learner_pose(name: str) -> tuple[str, dict[str, Any], str]:
    """A pose condition for the learner's observations -> ``(source, source kwargs,
    identity)`` for :func:`scorbot_gym.make_env`. Names as ``scorbot-gym compare`` takes them:
    ``oracle``; ``noisy@S`` / ``noisy@S:Y`` (x-y position std S metres, heading std Y degrees)
    with an optional ``:D`` (each estimate lost with probability D: ``pose_valid`` 0 and the
    last estimate held, as when the gripper hides the object); ``manifold`` (the default
    pose-manifold models with no privileged input, as ``compare``'s ``manifold``: background
    masks, recognised identity). One-line error for anything else."""
    from scorbot_gym.evaluation import compare  # lazily: evaluation imports rl

    if name == "oracle":
        return "oracle", {}, "given"
    if name == "manifold":
        (cond,) = compare.pose_conditions(["manifold"])
        return cond.source, dict(cond.kwargs), cond.identity
    if name.startswith("noisy@"):
        parts = name[len("noisy@") :].split(":")
        try:
            dropout = float(parts[2]) if len(parts) == 3 else 0.0
            if len(parts) > 3 or not 0.0 <= dropout <= 1.0:
                raise ValueError
            pos, yaw = compare.noise_level(":".join(parts[:2]))
        except (ValueError, IndexError):
            pass
        else:
            kwargs = {"pos_sigma_m": pos, "yaw_sigma_deg": yaw, "dropout": dropout}
            return "noisy_oracle", kwargs, "given"
    raise ValueError(
        f"learner pose {name!r}: expected oracle, manifold, or noisy@S[:Y[:D]] (position std "
        "in metres, heading std in degrees, dropout probability), e.g. noisy@0.02:20:0.5"
    )


def make_learner_envs(
    config: ImitationConfig, env_id: str = "ScorbotGraspCartesian-v0", **env_kwargs: Any
) -> list[gym.Env]:
    """One env per ``config.poses`` entry, in order (what :func:`train_imitation` takes);
    ``env_kwargs`` go to every one (``objects`` defaults to ``config.objects``). ``manifold``
    gets the default models (trained on first use and cached), loaded once for all."""
    if config.objects is not None:
        env_kwargs.setdefault("objects", list(config.objects))
    envs = []
    models = None
    for name in config.poses:
        source, kwargs, identity = learner_pose(name)
        if source == "manifold":
            if models is None:
                from scorbot_gym.perception.training import default_pose_models

                models = default_pose_models(progress=False)
            missing = sorted(set(env_kwargs.get("objects") or ()) - set(models.object_names()))
            if missing:
                raise ValueError(
                    f"the manifold learner pose has no pose models of {missing}: train "
                    "those objects with oracle or noisy poses only"
                )
            kwargs["models"] = models
        envs.append(
            make_env(env_id, pose=source, pose_kwargs=kwargs, identity=identity, **env_kwargs)
        )
    return envs


def _collect_round_robin(
    envs: Sequence[gym.Env], seeds: Sequence[int], **kwargs: Any
) -> list[LabelledEpisode]:
    """:func:`collect_episodes` with episode ``i`` on ``envs[i % len(envs)]``, in seed order
    (one env: exactly ``collect_episodes(env, seeds)``)."""
    seeds = list(seeds)
    by_env = [collect_episodes(env, seeds[i :: len(envs)], **kwargs) for i, env in enumerate(envs)]
    out: list[LabelledEpisode] = []
    for j in range(len(seeds)):
        out.append(by_env[j % len(envs)][j // len(envs)])
    return out


def _skeleton(env: gym.Env, config: ImitationConfig, extra: dict | None = None) -> ImitationPolicy:
    """An untrained policy for ``env`` (for feature extraction and the metadata)."""
    classes = tuple(env.get_wrapper_attr("class_names"))
    shapes = {k: list(env.observation_space[k].shape) for k in OBSERVATION_KEYS}
    shapes["object_class"] = [len(classes)]
    meta = {
        "format": FORMAT,
        "version": VERSION,
        "algo": ALGO,
        "uses_scripted_controller": False,
        "action_type": env.get_wrapper_attr("action_type"),
        "classes": list(classes),
        "observation_shapes": shapes,
        "history": asdict(config.history),
        "object_features": config.object_features,
        "features": "observation_features + previous actions + gripper-command history "
        "(scorbot_gym.policies.imitation)",
        "network": {
            "hidden": list(config.hidden),
            "activation": "relu",
            "outputs": "5 arm (tanh) + 1 gripper logit (sign)",
        },
        **(extra or {}),
    }
    n = n_features(len(classes), config.history, config.object_features)
    sizes = [n, *config.hidden, 6]
    weights = [np.zeros((a, b), np.float32) for a, b in zip(sizes, sizes[1:], strict=False)]
    biases = [np.zeros(b, np.float32) for b in sizes[1:]]
    return ImitationPolicy(MLP(weights, biases), np.zeros(n), np.ones(n), meta)


def fit_policy(
    policy: ImitationPolicy,
    feats: np.ndarray,
    labels: np.ndarray,
    config: ImitationConfig,
    seed: int,
    warm_start: bool = False,
) -> list[float]:
    """Fit the policy's MLP (and its feature normalisation) to ``labels``: MSE on the arm's
    tanh outputs, binary cross-entropy on the gripper logit. Returns the loss curve."""
    import torch as th

    th.set_num_threads(config.torch_threads)
    th.manual_seed(seed)
    rng = np.random.default_rng(seed)
    # Statistics over the rows with a pose estimate: the placeholder zeros before the first
    # one (lost estimates, e.g. noisy@S:Y:D) would inflate the position features' spread
    # several-fold and cost the policy its resolution where it has a pose.
    estimated = feats[:, AGE_FEATURE] < 1.0 - 1e-6
    stats = feats[estimated] if estimated.any() else feats
    policy.mean = stats.mean(axis=0).astype(np.float32)
    policy.std = stats.std(axis=0).astype(np.float32)
    x = th.as_tensor(policy.normalise(feats))
    arm = th.as_tensor(np.clip(labels[:, :-1], -1.0, 1.0), dtype=th.float32)
    grip = th.as_tensor((labels[:, -1] > 0).astype(np.float32))
    sizes = [x.shape[1], *config.hidden, 6]
    layers: list[th.nn.Module] = []
    for i, (a, b) in enumerate(zip(sizes, sizes[1:], strict=False)):
        layers.append(th.nn.Linear(a, b))
        if i < len(sizes) - 2:
            layers.append(th.nn.ReLU())
    net = th.nn.Sequential(*layers)
    linears = [m for m in net if isinstance(m, th.nn.Linear)]
    if warm_start:
        with th.no_grad():
            for lin, w, b in zip(linears, policy.net.weights, policy.net.biases, strict=True):
                lin.weight.copy_(th.as_tensor(w.T))
                lin.bias.copy_(th.as_tensor(b))
    opt = th.optim.AdamW(
        net.parameters(), lr=config.learning_rate, weight_decay=config.weight_decay
    )
    sched = th.optim.lr_scheduler.CosineAnnealingLR(opt, config.fit_steps)
    losses = []
    for _ in range(config.fit_steps):
        idx = th.as_tensor(rng.integers(0, len(x), config.batch_size))
        out = net(x[idx])
        loss = th.nn.functional.mse_loss(th.tanh(out[:, :-1]), arm[idx])
        loss = loss + th.nn.functional.binary_cross_entropy_with_logits(out[:, -1], grip[idx])
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        losses.append(float(loss.item()))
    policy.net = MLP(
        [lin.weight.detach().numpy().T.copy() for lin in linears],
        [lin.bias.detach().numpy().copy() for lin in linears],
    )
    return losses


def _init_policy(config: ImitationConfig, skeleton: ImitationPolicy) -> ImitationPolicy | None:
    """``config.init_policy`` loaded and checked against the policy being trained (the same
    features, classes and network layout); one-line error otherwise."""
    if config.init_policy is None:
        return None
    init = ImitationPolicy.load(init_policy_path(config.init_policy))
    shapes = [w.shape for w in init.net.weights]
    want = [w.shape for w in skeleton.net.weights]
    if shapes != want or init.classes != skeleton.classes:
        raise ValueError(
            f"init_policy {config.init_policy!r} does not fit this run: layers {shapes} and "
            f"{len(init.classes)} classes, this config gives {want} and {len(skeleton.classes)}"
        )
    return init


def _init_training(init: ImitationPolicy | None) -> dict[str, Any]:
    """The starting policy's recorded training cost (zeros when training from scratch)."""
    t = (init.meta.get("training") or {}) if init is not None else {}
    return {
        "demonstration_episodes": int(t.get("demonstration_episodes", 0)),
        "dagger_episodes": int(t.get("dagger_episodes", 0)),
        "env_steps": int(t.get("env_steps", 0)),
        "wall_time_s": float(t.get("wall_time_s", 0.0)),
    }


def _success_by_pose(episodes: Sequence[LabelledEpisode], poses: Sequence[str]) -> dict:
    """A DAgger round's success per learner pose (episode ``i`` ran under ``poses[i % n]``)."""
    return {
        name: float(np.mean([ep.success for ep in episodes[i :: len(poses)]]))
        for i, name in enumerate(poses)
        if episodes[i :: len(poses)]
    }


def label_accuracy(policy: ImitationPolicy, feats: np.ndarray, labels: np.ndarray) -> dict:
    """How closely the policy reproduces the labels (arm RMSE, gripper sign agreement)."""
    pred = to_action(policy.net(policy.normalise(feats)))
    return {
        "arm_rmse": float(np.sqrt(np.mean((pred[:, :-1] - np.clip(labels[:, :-1], -1, 1)) ** 2))),
        "gripper_agreement": float(np.mean((pred[:, -1] > 0) == (labels[:, -1] > 0))),
    }


def train_imitation(
    env: gym.Env | Sequence[gym.Env],
    config: ImitationConfig,
    demonstrations: Sequence[LabelledEpisode] | DemonstrationSet | None = None,
    progress: Callable[[str], None] | None = None,
    on_round: Callable[[ImitationPolicy, dict[str, Any]], None] | None = None,
) -> tuple[ImitationPolicy, dict[str, Any]]:
    """BC on the demonstrations (recorded with :func:`collect_episodes`, a
    :class:`DemonstrationSet` read from a dataset, or collected here: ``config.demos`` seeds
    of ``config.seed``'s block of :data:`scorbot_gym.seeds.DEMONSTRATIONS`), then
    ``config.dagger_rounds`` DAgger rounds on seeds of its :data:`~scorbot_gym.seeds.DAGGER`
    block. Returns the policy and the training record (also in its meta, with
    ``trained_by`` and ``provenance``: :mod:`scorbot_gym.rl.provenance`).

    A :class:`DemonstrationSet` whose action type differs from the env's is refused (one-line
    error), and its settings (episodes, DART sigma, seeds, dataset id and hash) are recorded in
    place of ``config.demos`` and ``config.dart_sigma``.

    ``env``: one env per ``config.poses`` entry (:func:`make_learner_envs`), episode ``i`` on
    ``env[i % n]``; a single env stands for ``config.poses == ("oracle",)`` whatever its pose
    source (the caller's choice). ``on_round(policy, round_record)`` is called after every fit
    (BC, then each DAgger round), e.g. to save a checkpoint of a long run."""
    envs = [env] if isinstance(env, gym.Env) else list(env)
    if len(envs) != len(config.poses):
        raise ValueError(
            f"give one env per learner pose: {len(config.poses)} poses {list(config.poses)}, "
            f"{len(envs)} envs (make_learner_envs builds them)"
        )
    say = progress or (lambda _msg: None)
    source = _demonstration_source(demonstrations, envs[0])
    start = time.perf_counter()
    rng = np.random.default_rng(config.seed)
    if demonstrations is None:
        seeds = seed_ranges.DEMONSTRATIONS.block(config.seed, config.demos)
        source.update(episodes=config.demos, seeds=_span(seeds), dart_sigma=config.dart_sigma)
        demonstrations = _collect_round_robin(envs, seeds, dart_sigma=config.dart_sigma, rng=rng)
    data = list(demonstrations)
    policy = _skeleton(envs[0], config)
    init = _init_policy(config, policy)
    if init is not None:
        policy.net = init.net
    pairs = [episode_features(ep, policy) for ep in data]
    feats = np.concatenate([f for f, _ in pairs])
    labels = np.concatenate([y for _, y in pairs])
    losses = fit_policy(
        policy, feats, labels, config, seed=config.seed, warm_start=init is not None
    )
    rounds = [
        {
            "round": 0,
            "beta": 1.0,
            "episodes": len(data),
            "success": float(np.mean([ep.success for ep in data])),
            "env_steps": int(sum(len(ep) for ep in data)),
            "final_loss": float(np.mean(losses[-100:])),
            **label_accuracy(policy, feats, labels),
        }
    ]
    say(f"BC on {len(data)} demonstrations ({len(feats)} steps): {rounds[-1]}")
    if on_round is not None:
        on_round(policy, rounds[-1])
    dagger_seeds = seed_ranges.DAGGER.block(
        config.seed, config.dagger_rounds * config.dagger_episodes
    )
    for r in range(1, config.dagger_rounds + 1):
        beta = config.beta * config.beta_decay ** (r - 1)
        seeds = dagger_seeds[(r - 1) * config.dagger_episodes : r * config.dagger_episodes]
        new = _collect_round_robin(
            envs,
            seeds,
            learner=policy,
            beta=beta,
            rng=rng,
            sync_expert=config.sync_expert,
            expert_keeps_close=config.expert_keeps_close,
        )
        data += new
        new_pairs = [episode_features(ep, policy) for ep in new]
        feats = np.concatenate([feats, *[f for f, _ in new_pairs]])
        labels = np.concatenate([labels, *[y for _, y in new_pairs]])
        losses = fit_policy(policy, feats, labels, config, seed=config.seed + r, warm_start=True)
        rounds.append(
            {
                "round": r,
                "beta": beta,
                "episodes": len(new),
                "success": float(np.mean([ep.success for ep in new])),
                "success_by_pose": _success_by_pose(new, config.poses),
                "env_steps": int(sum(len(ep) for ep in new)),
                "final_loss": float(np.mean(losses[-100:])),
                **label_accuracy(policy, feats, labels),
            }
        )
        say(f"DAgger round {r} (beta {beta:.3f}): {rounds[-1]}")
        if on_round is not None:
            on_round(policy, rounds[-1])
    before = _init_training(init)  # what the starting policy cost, counted in the totals
    config_record = {**asdict(config), "hidden": list(config.hidden)}
    if source["kind"] != "collected":  # what the given demonstrations were, not the defaults
        config_record["demos"] = len(demonstrations)
        config_record["dart_sigma"] = source.get("dart_sigma", "unknown")
    record = {
        "config": config_record,
        "demonstration_episodes": len(demonstrations) + before["demonstration_episodes"],
        "dagger_episodes": int(sum(r["episodes"] for r in rounds[1:])) + before["dagger_episodes"],
        "env_steps": int(sum(r["env_steps"] for r in rounds)) + before["env_steps"],
        "labelled_steps": int(len(feats)),
        "wall_time_s": time.perf_counter() - start + before["wall_time_s"],
        "init_policy": None if init is None else {"source": config.init_policy, **before},
        "rounds": rounds,
        "expert": "ScriptedGraspPolicy with the oracle pose (labels only; not used at test time)",
        "learner_poses": list(config.poses),
    }
    policy.meta["training"] = record
    policy.meta["saw_scripted_controller"] = {  # in training only, as labeller
        "residual_base": False,
        "bc_demo_episodes": record["demonstration_episodes"],
        "dagger_labelled_episodes": record["dagger_episodes"],
    }
    policy.meta.update(
        imitation_provenance("imitation", config, config.poses, envs, source, dagger_seeds, init)
    )
    return policy, record


def _span(seeds: range) -> dict[str, Any] | None:
    from scorbot_gym.rl.provenance import seed_span

    return seed_span(seeds)


def _demonstration_source(demonstrations: Any, env: gym.Env) -> dict[str, Any]:
    """What the demonstrations are (for the provenance); a dataset recorded for another action
    type than ``env``'s is a one-line error."""
    if demonstrations is None:
        return {"kind": "collected"}
    if not isinstance(demonstrations, DemonstrationSet):
        seeds = sorted(int(ep.seed) for ep in demonstrations)
        return {"kind": "given", "episodes": len(seeds), "seeds": seeds}
    settings = dict(demonstrations.settings)
    want = env.get_wrapper_attr("action_type")
    have = settings.get("action_type")
    name = settings.get("dataset_id", "the demonstrations")
    if have is None:
        import warnings

        warnings.warn(
            f"dataset {name!r} records no action type (recorded before it was); assuming "
            f"{want} actions, as the env's",
            stacklevel=3,
        )
        settings["action_type"] = "not recorded"
    elif have != want:
        raise ValueError(
            f"dataset {name!r} holds {have} actions but the env takes {want} actions: train "
            f"with action_type {have!r}, or record the demonstrations with --action-type {want}"
        )
    return {"kind": "dataset", **settings, "episodes": len(demonstrations)}


def imitation_provenance(
    trained_by: str,
    config: Any,
    poses: Sequence[str],
    envs: Sequence[gym.Env],
    source: dict[str, Any],
    dagger_seeds: range,
    init: Any = None,
) -> dict[str, Any]:
    """``trained_by`` and ``provenance`` of an imitation-trained policy: the demonstrations
    (``source``), the DAgger seeds, the learner's pose conditions (``poses``, one per env;
    none for a policy that reads no pose) and the pose models behind each (``None`` where it
    has none: the oracle)."""
    from scorbot_gym.rl import provenance

    by_pose = {name: provenance.env_pose_models(env) for name, env in zip(poses, envs, strict=True)}
    data = {
        "demonstrations": source,
        "dagger": provenance.seed_span(dagger_seeds),
        "learner_poses": list(poses),
    }
    if init is not None:
        data["init_policy"] = {
            "name": config.init_policy,
            **provenance.policy_identity(init_policy_path(config.init_policy), init.meta),
        }
    models = by_pose if any(v is not None for v in by_pose.values()) else None
    return provenance.record(trained_by, data, models)


def init_policy_path(name: str):
    """The folder ``init_policy`` names (``learned``: the shipped policy)."""
    from scorbot_gym.policies.imitation import SHIPPED_LEARNED_POLICY

    return SHIPPED_LEARNED_POLICY if name == "learned" else name
