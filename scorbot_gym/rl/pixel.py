"""Imitation learning of the pixel policy (:mod:`scorbot_gym.policies.pixel`): the state
policy's recipe, BC from scripted demonstrations with DART noise then DAgger, with camera
images in place of the pose estimate.

Collection and DAgger are :func:`scorbot_gym.rl.imitation.collect_episodes` unchanged (in
``jobs`` worker processes if asked: rendering, not the fit, is what a run waits for): the
scripted controller acts (demonstrations) or labels (DAgger) from the **oracle** pose in
``info``, the learner acts from its frames, proprioception and action history. Episodes store
only what the policy reads, each camera's image as its 84 x 84 uint8 frame (``keep``), so
memory grows by ~21 kB per camera and step; a frame stack is gathered from the stored steps
at fitting time (:func:`stack_index`), not stored. Fitting can add DrQ's random-shift
augmentation (Kostrikov et al. 2021; Yarats et al. 2021: pad by ``shift`` pixels, crop back
at a random offset per sample), the standard regulariser for a small CNN; it is off by default
because here one pixel is about a centimetre on the table, and the shift bought nothing when
measured with the single-frame top-camera policy. Training uses CUDA when it is
available (``device="auto"``); the saved policy runs on the CPU.

**Validation** (robomimic's protocol): ``val_demos`` demonstrations from their own seeds are
never fitted, and say how well the labels are reproduced off the training set;
``val_episodes`` rollouts of the learner alone, on the training-evaluation seeds, after every
``val_every`` fitting steps and at the end of every fit, choose the checkpoint the run returns
(highest rollout success, then lowest held-out label error, then the later). DAgger always
collects with the latest weights.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import gymnasium as gym
import numpy as np

from scorbot_gym import seeds as seed_ranges
from scorbot_gym.policies.imitation import ActionHistory, HistorySpec, to_action
from scorbot_gym.policies.pixel import (
    NetSpec,
    PixelPolicy,
    n_vector_features,
    new_meta,
    stack_frames,
)
from scorbot_gym.rl.imitation import (
    LabelledEpisode,
    check_expert_options,
    collect_episodes,
    imitation_provenance,
)
from scorbot_gym.rl.provenance import seed_span


@dataclass
class PixelImitationConfig:
    """Everything that defines a pixel imitation run (recorded in ``policy.json``)."""

    # The defaults are the best recipe measured (benchmarks/README.md, "The pixel arm"): more
    # demonstrations and fitting paid, the random shift did not, more DAgger rounds hurt.
    demos: int = 400
    dart_sigma: float = 0.2
    dagger_rounds: int = 3
    dagger_episodes: int = 60
    beta: float = 0.5
    beta_decay: float = 0.5
    net: NetSpec = field(default_factory=NetSpec)
    #: cameras the policy reads (``net.cameras`` follows their number)
    cameras: tuple[str, ...] = ("top",)
    fit_steps: int = 8000
    batch_size: int = 256
    learning_rate: float = 3e-4
    weight_decay: float = 1e-5
    shift: int = 0
    history: HistorySpec = field(default_factory=HistorySpec)
    seed: int = 0
    torch_threads: int = 1
    jobs: int = 1  # collection processes (the episodes do not depend on it)
    sync_expert: bool = True
    #: the DAgger labeller's decision to close stands until the learner closes
    #: (:class:`~scorbot_gym.rl.imitation.ExecutedActionExpert` ``keeps_close``)
    expert_keeps_close: bool = False
    #: held-out demonstrations (own seeds, never fitted): label error off the training set
    val_demos: int = 0
    #: validation rollouts per checkpoint (0: the run returns its last weights)
    val_episodes: int = 0
    #: fitting steps between checkpoints within a fit (0: only at the end of each fit)
    val_every: int = 0
    device: str = "auto"

    def __post_init__(self) -> None:
        if isinstance(self.history, dict):
            self.history = HistorySpec.from_record(self.history)
        if self.history.pose_window:
            raise ValueError("a pixel policy reads no pose estimate: history.pose_window must be 0")
        if isinstance(self.net, dict):
            self.net = NetSpec(**self.net)
        if isinstance(self.cameras, str) or not self.cameras:
            raise ValueError(f"cameras must be a non-empty list of names, got {self.cameras!r}")
        self.cameras = tuple(str(c) for c in self.cameras)
        if len(set(self.cameras)) != len(self.cameras):
            raise ValueError(f"cameras must not repeat, got {list(self.cameras)}")
        self.net = replace(self.net, cameras=len(self.cameras))
        for name in ("demos", "fit_steps", "batch_size", "torch_threads", "jobs"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        for name in ("dagger_rounds", "dagger_episodes", "shift", "val_demos", "val_episodes"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if not 0.0 <= self.beta <= 1.0 or not 0.0 <= self.beta_decay <= 1.0:
            raise ValueError(
                f"beta and beta_decay must be in [0, 1], got {self.beta}, {self.beta_decay}"
            )
        if self.val_demos and self.demos > seed_ranges.BLOCK // 2:
            raise ValueError(  # the held-out demonstrations start half-way into the block
                f"with val_demos, demos must be <= {seed_ranges.BLOCK // 2}, got {self.demos}"
            )
        if self.val_every < 0 or (self.val_every and not self.val_episodes):
            raise ValueError(
                f"val_every must be >= 0 and needs val_episodes > 0, got val_every "
                f"{self.val_every}, val_episodes {self.val_episodes}"
            )
        if self.dart_sigma < 0:
            raise ValueError(f"dart_sigma must be >= 0, got {self.dart_sigma}")
        check_expert_options(self.sync_expert, self.expert_keeps_close)
        seed_ranges.check_run_seed(self.seed)
        if self.device not in ("auto", "cpu", "cuda"):
            raise ValueError(f"device must be 'auto', 'cpu' or 'cuda', got {self.device!r}")

    def torch_device(self) -> str:
        import torch as th

        if self.device == "auto":
            return "cuda" if th.cuda.is_available() else "cpu"
        return self.device


def skeleton(env: gym.Env, config: PixelImitationConfig) -> PixelPolicy:
    """An untrained pixel policy for ``env``, which must render ``config.cameras``."""
    classes = tuple(env.get_wrapper_attr("class_names"))
    keys = [f"{c}_rgb" for c in config.cameras]
    missing = [k for k in keys if k not in env.observation_space.spaces]
    if missing:
        raise ValueError(
            f"the pixel policy trains on {missing}: make the env with "
            f"cameras={list(config.cameras)}"
        )
    sizes = {tuple(env.observation_space[k].shape[:2]) for k in keys}
    if len(sizes) != 1:
        raise ValueError(f"the cameras must render one size, the env gives {sorted(sizes)}")
    height, width = sizes.pop()
    meta = new_meta(
        classes=classes,
        action_type=env.get_wrapper_attr("action_type"),
        cameras=config.cameras,
        render_size=(width, height),
        history=config.history,
    )
    n = n_vector_features(len(classes), config.history)
    return PixelPolicy(config.net, None, np.zeros(n), np.ones(n), meta)


def episode_arrays(
    episode: LabelledEpisode, policy: PixelPolicy
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each step's own frames (T, cameras x C, S, S) uint8 (unstacked: :func:`stack_index`
    gathers a stack), raw vectors (T, n) with the executed-action history, and labels (T, 6)
    of an episode's acted steps."""
    history = ActionHistory(policy.history_spec)
    keys = list(episode.observations)
    frames, vectors = [], []
    for t in range(len(episode)):
        obs = {k: episode.observations[k][t] for k in keys}
        frames.append(policy.current_frames(obs))
        vectors.append(policy.vector_features(obs, history))
        history.push(episode.actions[t], obs)
    return np.stack(frames), np.stack(vectors), episode.labels[: len(episode)]


def stack_index(lengths: Sequence[int], frame_stack: int) -> np.ndarray:
    """(N, frame_stack) row indices into the concatenated steps of episodes of ``lengths``:
    for every step, its episode's last ``frame_stack`` steps, the oldest first, the episode's
    first step repeated before it has that many (as :class:`~scorbot_gym.policies.pixel.
    FrameHistory` pads)."""
    rows = []
    start = 0
    back = np.arange(frame_stack - 1, -1, -1)
    for n in lengths:
        t = np.arange(n)[:, None]
        rows.append(start + np.maximum(t - back, 0))
        start += n
    return np.concatenate(rows) if rows else np.zeros((0, frame_stack), np.int64)


def gather_frames(frames, index, rows, cameras: int):
    """The network's input for ``rows`` (numpy or torch alike): their stacks of frames."""
    return stack_frames(frames[index[rows]], cameras)


def random_shift(frames, pad: int, groups: int = 1):
    """DrQ-v2's random shift: replicate-pad by ``pad`` and resample each image at a random
    integer offset in [-pad, pad] (one ``grid_sample`` for the whole batch). With ``groups``,
    the channels split into that many cameras, each shifted on its own (a camera's stacked
    frames move together)."""
    import torch as th
    import torch.nn.functional as F

    if pad == 0:
        return frames
    if groups > 1:
        parts = th.chunk(frames, groups, dim=1)
        return th.cat([random_shift(part, pad) for part in parts], dim=1)
    n, _, h, w = frames.shape
    padded = F.pad(frames, (pad, pad, pad, pad), mode="replicate")
    eps = 1.0 / (h + 2 * pad)
    arange = th.linspace(-1.0 + eps, 1.0 - eps, h + 2 * pad, device=frames.device)[:h]
    arange = arange.unsqueeze(0).repeat(h, 1).unsqueeze(2)
    base = th.cat([arange, arange.transpose(1, 0)], dim=2).unsqueeze(0).repeat(n, 1, 1, 1)
    shift = th.randint(0, 2 * pad + 1, (n, 1, 1, 2), device=frames.device).float()
    shift *= 2.0 / (h + 2 * pad)
    return F.grid_sample(padded, base + shift, padding_mode="zeros", align_corners=False)


def fit_pixel_policy(
    policy: PixelPolicy,
    frames: np.ndarray,
    vectors: np.ndarray,
    labels: np.ndarray,
    config: PixelImitationConfig,
    seed: int,
    warm_start: bool = False,
    lengths: Sequence[int] | None = None,
    on_checkpoint: Callable[[int], None] | None = None,
) -> list[float]:
    """Fit the policy's network (and its vector normalisation) to ``labels``: MSE on the arm's
    tanh outputs, binary cross-entropy on the gripper logit, frames randomly shifted.
    ``frames`` are each step's own; ``lengths`` (the episodes', in order; default: one)
    say which steps a frame stack gathers. Returns the loss curve; the fitted weights are
    copied back into ``policy`` (CPU), also before every ``on_checkpoint(step)``, called
    every ``config.val_every`` steps."""
    import torch as th
    import torch.nn.functional as F

    from scorbot_gym.policies.pixel import build_network

    th.set_num_threads(config.torch_threads)
    th.manual_seed(seed)
    device = config.torch_device()
    th.backends.cudnn.benchmark = device == "cuda"  # fixed input sizes: let cuDNN pick
    gen = th.Generator(device=device).manual_seed(seed)
    policy.mean = vectors.mean(axis=0).astype(np.float32)
    policy.std = vectors.std(axis=0).astype(np.float32)
    x_img = th.as_tensor(frames).to(device)  # uint8: 1/4 of the memory of floats
    index = stack_index([len(labels)] if lengths is None else lengths, config.net.frame_stack)
    x_index = th.as_tensor(index).to(device)
    x_vec = th.as_tensor(policy.normalise(vectors)).to(device)
    arm = th.as_tensor(np.clip(labels[:, :-1], -1.0, 1.0), dtype=th.float32).to(device)
    grip = th.as_tensor((labels[:, -1] > 0).astype(np.float32)).to(device)
    net = build_network(config.net, policy.n_vector).to(device)
    if warm_start:
        net.load_state_dict(policy.net.state_dict())
    opt = th.optim.AdamW(
        net.parameters(), lr=config.learning_rate, weight_decay=config.weight_decay
    )
    sched = th.optim.lr_scheduler.CosineAnnealingLR(opt, config.fit_steps)
    losses = []
    cameras = config.net.cameras

    def copy_back() -> None:
        policy.load_state({k: v.detach().cpu().numpy() for k, v in net.state_dict().items()})
        policy.net.eval()

    net.train()
    for step in range(1, config.fit_steps + 1):
        idx = th.randint(0, len(x_vec), (config.batch_size,), device=device, generator=gen)
        stacks = gather_frames(x_img, x_index, idx, cameras)
        img = random_shift(stacks.float() / 255.0, config.shift, groups=cameras)
        out = net(img, x_vec[idx])
        loss = F.mse_loss(th.tanh(out[:, :-1]), arm[idx])
        loss = loss + F.binary_cross_entropy_with_logits(out[:, -1], grip[idx])
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        losses.append(loss.detach())
        if on_checkpoint is not None and config.val_every and step % config.val_every == 0:
            if step < config.fit_steps:  # the end of the fit is every caller's checkpoint
                copy_back()
                on_checkpoint(step)
                net.train()
    copy_back()
    return [float(v) for v in th.stack(losses).cpu().numpy()]


def label_accuracy(
    policy: PixelPolicy,
    frames: np.ndarray,
    vectors: np.ndarray,
    labels: np.ndarray,
    lengths: Sequence[int] | None = None,
) -> dict[str, float]:
    """How closely the policy reproduces the labels (arm RMSE, gripper sign agreement),
    on at most 4096 evenly spaced steps (CPU inference)."""
    index = stack_index([len(labels)] if lengths is None else lengths, policy.net_spec.frame_stack)
    pick = np.linspace(0, len(labels) - 1, min(len(labels), 4096)).astype(int)
    cameras = policy.net_spec.cameras
    pred = np.concatenate(
        [
            to_action(
                policy.raw_outputs(
                    gather_frames(frames, index, pick[i : i + 512], cameras),
                    vectors[pick[i : i + 512]],
                )
            )
            for i in range(0, len(pick), 512)
        ]
    )
    y = labels[pick]
    return {
        "arm_rmse": float(np.sqrt(np.mean((pred[:, :-1] - np.clip(y[:, :-1], -1, 1)) ** 2))),
        "gripper_agreement": float(np.mean((pred[:, -1] > 0) == (y[:, -1] > 0))),
    }


def train_pixel_imitation(
    env: gym.Env,
    config: PixelImitationConfig,
    progress: Callable[[str], None] | None = None,
    on_round: Callable[[PixelPolicy, dict[str, Any]], None] | None = None,
    env_kwargs: dict[str, Any] | None = None,
) -> tuple[PixelPolicy, dict[str, Any]]:
    """BC on ``config.demos`` DART-noised scripted demonstrations (``config.seed``'s block of
    :data:`scorbot_gym.seeds.DEMONSTRATIONS`), then ``config.dagger_rounds`` DAgger rounds on
    its block of :data:`~scorbot_gym.seeds.DAGGER`, the scripted controller
    labelling from the oracle pose. ``env`` renders ``config.camera`` and has ``class_names``
    (e.g. ``make_env(pose="oracle", include_class=True, cameras=["top"], image_width=112,
    image_height=84)``; its pose entries are there for the expert's bookkeeping only, the
    policy never reads them). Returns the policy and the training record (also in its meta).

    ``on_round(policy, round_record)`` is called after every fit (BC, then each DAgger round)
    with the record so far already in ``policy.meta`` (``"rounds_done"`` of
    ``config.dagger_rounds + 1``): save it there and a run cut short still leaves a policy.

    With ``config.jobs > 1`` the episodes are collected in that many worker processes, each
    with its own env made by :func:`scorbot_gym.make_env` from ``env_kwargs`` (the keywords
    ``env`` was made with). Every episode draws its DART noise and who acts from its own
    stream (``config.seed``, the round, the episode's seed), so the data do not depend on
    ``jobs``.

    With ``config.val_episodes`` the returned policy holds the checkpoint the validation
    rollouts chose (module docstring); ``policy.meta["training"]["validation"]`` lists every
    checkpoint's scores."""
    say = progress or (lambda _msg: None)
    start = time.perf_counter()
    policy = skeleton(env, config)

    def collect(round_index: int, seeds: range, learner: PixelPolicy | None, beta: float):
        return collect_pixel_episodes(
            env,
            seeds,
            policy,
            config,
            round_index=round_index,
            learner=learner,
            beta=beta,
            env_kwargs=env_kwargs,
        )

    seeds = seed_ranges.DEMONSTRATIONS.block(config.seed, config.demos)
    dagger_seeds = seed_ranges.DAGGER.block(
        config.seed, config.dagger_rounds * config.dagger_episodes
    )
    source = {
        "kind": "collected",
        "episodes": config.demos,
        "seeds": seed_span(seeds),
        "dart_sigma": config.dart_sigma,
    }
    policy.meta.update(
        imitation_provenance("pixel_imitation", config, [], [], source, dagger_seeds)
    )
    validation = Validation(policy, config, collect)
    if config.val_demos:
        validation.hold_out(collect(HELD_OUT_STREAM, validation.demo_seeds, None, 1.0))
    frames = vectors = labels = None
    lengths: list[int] = []
    rounds: list[dict[str, Any]] = []
    for r in range(config.dagger_rounds + 1):
        if r == 0:  # behaviour cloning on the demonstrations
            beta, new = 1.0, collect(0, seeds, None, 1.0)
        else:
            beta = config.beta * config.beta_decay ** (r - 1)
            chunk = dagger_seeds[(r - 1) * config.dagger_episodes : r * config.dagger_episodes]
            new = collect(r, chunk, policy, beta)
        f, v, y, n = _concat([episode_arrays(ep, policy) for ep in new])
        frames = f if frames is None else np.concatenate([frames, f])
        vectors = v if vectors is None else np.concatenate([vectors, v])
        labels = y if labels is None else np.concatenate([labels, y])
        lengths = [*lengths, *n]
        fit_t0 = time.perf_counter()
        losses = fit_pixel_policy(
            policy,
            frames,
            vectors,
            labels,
            config,
            seed=config.seed + r,
            warm_start=r > 0,
            lengths=lengths,
            on_checkpoint=lambda step, r=r: validation.checkpoint(r, step),
        )
        fit_s = time.perf_counter() - fit_t0
        validation.checkpoint(r, config.fit_steps)
        rounds.append(
            _round_record(r, beta, new, losses, fit_s, policy, frames, vectors, labels, lengths)
        )
        what = f"BC on {len(new)} demonstrations" if r == 0 else f"DAgger round {r}"
        say(f"{what} (beta {beta:.3f}, {len(labels)} steps in all): {rounds[-1]}")
        if on_round is not None:
            pol = _record(policy, config, start, rounds, frames, labels, validation)
            on_round(pol, rounds[-1])
    validation.restore_best()
    _record(policy, config, start, rounds, frames, labels, validation)
    return policy, policy.meta["training"]


#: the random streams (``collect``'s round index) of the held-out demonstrations' DART noise
#: and of the validation rollouts (the learner alone: nothing is drawn), apart from the rounds'
HELD_OUT_STREAM, ROLLOUT_STREAM = 10_000, 10_001


class Validation:
    """The run's validation: held-out demonstrations' label error and rollouts of the
    learner alone at every checkpoint; keeps the best checkpoint's weights and
    normalisation (module docstring: how it chooses)."""

    def __init__(self, policy: PixelPolicy, config: PixelImitationConfig, collect) -> None:
        self.policy, self.config, self.collect = policy, config, collect
        # past the half of the seed's demonstration block, never a training demonstration
        offset = seed_ranges.BLOCK // 2
        self.demo_seeds = seed_ranges.DEMONSTRATIONS.block(config.seed, config.val_demos, offset)
        self.rollout_seeds = seed_ranges.TRAINING_EVALUATION.seeds(config.val_episodes)
        self.held_out: tuple | None = None
        self.checkpoints: list[dict[str, Any]] = []
        self.best: tuple | None = None  # (key, weights, mean, std, record)

    def hold_out(self, episodes: Sequence[LabelledEpisode]) -> None:
        self.held_out = _concat([episode_arrays(ep, self.policy) for ep in episodes])

    def checkpoint(self, round_index: int, step: int) -> None:
        """Score the policy's current weights; remember them if they are the best so far."""
        cfg = self.config
        if not (cfg.val_episodes or cfg.val_demos):
            return
        t0 = time.perf_counter()
        record: dict[str, Any] = {"round": round_index, "fit_step": step}
        if self.held_out is not None:
            frames, vectors, labels, lengths = self.held_out
            acc = label_accuracy(self.policy, frames, vectors, labels, lengths)
            record.update({f"held_out_{k}": v for k, v in acc.items()})
        if cfg.val_episodes:
            episodes = self.collect(ROLLOUT_STREAM, self.rollout_seeds, self.policy, 0.0)
            record["rollout_success"] = float(np.mean([ep.success for ep in episodes]))
            record["rollout_episodes"] = len(episodes)
        record["wall_s"] = round(time.perf_counter() - t0, 2)
        self.checkpoints.append(record)
        key = (
            record.get("rollout_success", 0.0),
            -record.get("held_out_arm_rmse", 0.0),
            len(self.checkpoints),
        )
        if self.best is None or key > self.best[0]:
            pol = self.policy
            self.best = (key, pol.state_arrays(), pol.mean.copy(), pol.std.copy(), record)

    def restore_best(self) -> None:
        """Put the chosen checkpoint's weights and normalisation back into the policy."""
        if self.best is None:
            return
        _, state, mean, std, _record_ = self.best
        self.policy.load_state(state)
        self.policy.mean, self.policy.std = mean, std

    def summary(self) -> dict[str, Any]:
        return {
            "held_out_demonstrations": self.config.val_demos,
            "held_out_seeds": seed_span(self.demo_seeds) if self.config.val_demos else None,
            "rollout_episodes": self.config.val_episodes,
            "rollout_seeds": seed_span(self.rollout_seeds) if self.config.val_episodes else None,
            "chosen": None if self.best is None else self.best[4],
            "checkpoints": list(self.checkpoints),
        }


def collect_pixel_episodes(
    env: gym.Env,
    seeds: range,
    policy: PixelPolicy,
    config: PixelImitationConfig,
    *,
    round_index: int,
    learner: PixelPolicy | None = None,
    beta: float = 1.0,
    env_kwargs: dict[str, Any] | None = None,
) -> list[LabelledEpisode]:
    """One round's episodes (:func:`~scorbot_gym.rl.imitation.collect_episodes`, stored as
    ``policy``'s compact observations): demonstrations with DART noise when ``learner`` is
    None, else DAgger with the learner acting with probability ``1 - beta``. In
    ``config.jobs`` processes when it is above 1 (their envs from ``env_kwargs``); the same
    episodes either way."""
    if config.jobs > 1 and env_kwargs is None:
        raise ValueError(
            "jobs > 1 collects in worker processes: give env_kwargs, the make_env keywords "
            "of env, for their envs"
        )
    key = (config.seed % 2**32, round_index)
    sync = config.sync_expert and learner is not None
    kwargs = {
        "beta": beta,
        "sync_expert": sync,
        "expert_keeps_close": sync and config.expert_keeps_close,
    }
    if learner is None:
        kwargs["dart_sigma"] = config.dart_sigma
    if config.jobs == 1 or len(seeds) < 2:
        return _collect_seeds(env, seeds, key, policy, learner, kwargs)
    from scorbot_gym.evaluation.chunks import run_chunked

    blob = _policy_blob(learner if learner is not None else policy)
    acting = learner is not None

    def chunk_args(_task: int, n: int, first: int) -> tuple:
        return (env_kwargs, range(first, first + n), key, blob, acting, kwargs)

    done = run_chunked(_collect_chunk, [(len(seeds), seeds.start)], chunk_args, config.jobs)
    return [ep for chunk in done[0] for ep in chunk]


def _collect_seeds(env, seeds, key, policy, learner, kwargs) -> list[LabelledEpisode]:
    out = []
    for seed in seeds:
        rng = np.random.default_rng([*key, seed % 2**32])
        out += collect_episodes(
            env, [seed], learner=learner, rng=rng, keep=policy.compact_observation, **kwargs
        )
    return out


def _policy_blob(policy: PixelPolicy) -> tuple:
    """What rebuilds ``policy`` in a worker (plain arrays and dicts: they pickle)."""
    return (policy.net_spec, policy.state_arrays(), policy.mean, policy.std, policy.meta)


_WORKER_ENVS: dict[str, gym.Env] = {}  # a worker's env, built once per set of keywords


def _collect_chunk(env_kwargs, seeds, key, blob, with_learner, kwargs) -> list[LabelledEpisode]:
    """A worker's share of a round (module level: it pickles for spawned processes)."""
    import torch as th

    from scorbot_gym.envs.factory import make_env

    th.set_num_threads(1)  # one-sample predictions: threads only add contention
    name = repr(sorted(env_kwargs.items()))
    if name not in _WORKER_ENVS:
        _WORKER_ENVS[name] = make_env(**{"env_id": "ScorbotGraspCartesian-v0", **env_kwargs})
    env = _WORKER_ENVS[name]
    policy = PixelPolicy(*blob).bind(env)
    learner = policy if with_learner else None
    return _collect_seeds(env, seeds, key, policy, learner, kwargs)


def _record(
    policy: PixelPolicy,
    config: PixelImitationConfig,
    start: float,
    rounds: list[dict],
    frames: np.ndarray,
    labels: np.ndarray,
    validation: Validation,
) -> PixelPolicy:
    """Write the training record so far into the policy's meta (after every round)."""
    dagger = int(sum(r["episodes"] for r in rounds[1:]))
    policy.meta["training"] = {
        "config": asdict(config),
        "demonstration_episodes": config.demos,
        "dagger_episodes": dagger,
        "rounds_done": len(rounds),
        "rounds_planned": config.dagger_rounds + 1,
        "env_steps": int(sum(r["env_steps"] for r in rounds)),
        "labelled_steps": int(len(labels)),
        "frames_mb": round(frames.nbytes / 2**20, 1),
        "wall_time_s": time.perf_counter() - start,
        "fit_time_s": float(sum(r["fit_s"] for r in rounds)),
        "device": config.torch_device(),
        "rounds": list(rounds),
        "expert": "ScriptedGraspPolicy with the oracle pose (labels only; not used at test time)",
        "augmentation": f"random shift +-{config.shift} px (DrQ)",
        "cameras": list(config.cameras),
        "frame_stack": config.net.frame_stack,
        "validation": validation.summary(),
    }
    policy.meta["saw_scripted_controller"] = {  # in training only, as labeller
        "residual_base": False,
        "bc_demo_episodes": config.demos,
        "dagger_labelled_episodes": dagger,
    }
    return policy


def _concat(parts: Sequence[tuple[np.ndarray, ...]]) -> tuple[Any, ...]:
    """Episodes' (frames, vectors, labels) joined, and their lengths."""
    joined = tuple(np.concatenate([p[i] for p in parts]) for i in range(3))
    return (*joined, [len(p[2]) for p in parts])


def _round_record(
    r: int,
    beta: float,
    episodes: Sequence[LabelledEpisode],
    losses: list[float],
    fit_s: float,
    policy: PixelPolicy,
    frames: np.ndarray,
    vectors: np.ndarray,
    labels: np.ndarray,
    lengths: Sequence[int],
) -> dict[str, Any]:
    return {
        "round": r,
        "beta": beta,
        "episodes": len(episodes),
        "success": float(np.mean([ep.success for ep in episodes])),
        "env_steps": int(sum(len(ep) for ep in episodes)),
        "final_loss": float(np.mean(losses[-100:])),
        "fit_s": round(fit_s, 2),
        **label_accuracy(policy, frames, vectors, labels, lengths),
    }


def recipe_differences(pixel: dict[str, Any], state: dict[str, Any]) -> dict[str, list[str]]:
    """What the pixel arm and a state imitation policy share and what still differs besides
    the pose estimate, from their ``policy.json`` training records: a pixel-vs-pose difference
    is stated with the ``differs`` list beside it (the anchors' confounds: memory, cameras,
    the state policy's fixes, demonstrations, fitting, checkpoint choice)."""
    p, s = pixel["training"]["config"], state["training"]["config"]
    ph, sh = p["history"], s["history"]
    same: list[str] = []
    differs: list[str] = []

    def check(ok: bool, shared: str, apart: str) -> None:
        (same if ok else differs).append(shared if ok else apart)

    stack = int(p.get("net", {}).get("frame_stack", 1))
    window = int(sh.get("pose_window", 0))
    check(
        (stack > 1) == (window > 1),
        f"memory: the last {stack} frames / the last {window} pose estimates",
        f"memory: pixel sees {stack} frame(s), state the last {window} pose estimate(s)",
    )
    cameras = list(p.get("cameras") or [p.get("camera", "top")])
    check(
        "eye_in_hand" in cameras,
        f"cameras: {' + '.join(cameras)} (the wrist camera included)",
        f"cameras: {' + '.join(cameras)} only, no wrist camera",
    )
    check(
        ph.get("stall_steps", 0) == sh.get("stall_steps", 0),
        f"stall input: {sh.get('stall_steps', 0)} steps",
        f"stall input: pixel {ph.get('stall_steps', 0)}, state {sh.get('stall_steps', 0)} steps",
    )
    check(
        bool(p.get("expert_keeps_close")) == bool(s.get("expert_keeps_close")),
        f"keep-closing labels: {bool(s.get('expert_keeps_close'))}",
        f"keep-closing labels: pixel {bool(p.get('expert_keeps_close'))}, state "
        f"{bool(s.get('expert_keeps_close'))}",
    )
    episodes = [
        (c["demos"], c["dagger_rounds"], c["dagger_episodes"], c["dart_sigma"]) for c in (p, s)
    ]
    check(
        episodes[0] == episodes[1],
        "demonstrations: {} + {} x {} DAgger, DART sigma {}".format(*episodes[1]),
        "demonstrations: pixel {} + {} x {} DAgger (DART {}), state {} + {} x {} (DART {})".format(
            *episodes[0], *episodes[1]
        ),
    )
    val = pixel["training"].get("validation") or {}
    if val.get("rollout_episodes"):
        differs.append(
            f"checkpoint: pixel's chosen by {val['rollout_episodes']} validation rollouts per "
            "checkpoint, state's the last fit (favours the pixel arm)"
        )
    else:
        same.append("checkpoint: the last fit's, both")
    poses = s.get("poses")
    if poses and poses != ["oracle"]:
        differs.append(
            f"state learner trained on poses from {' and '.join(poses)}; tested on the oracle"
        )
    return {"same": same, "differs": differs}
