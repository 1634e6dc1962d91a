"""A stand-alone learned grasping policy (imitation + DAgger), with no scripted controller inside.

The network sees what :class:`~scorbot_gym.wrappers.PoseEstimateObservation` gives (proprio-
ception, the estimated object pose, ``pose_valid``/``pose_confidence``/``pose_age``, the
``object_class`` one-hot) plus a short history of **its own executed actions**:

- the previous ``previous_actions`` actions (6 each): how it was moving;
- the gripper commands of the last ``gripper_commands`` steps (+1 open / -1 closed): how long
  the fingers have been closing. The scripted controller lifts a fixed time after it starts
  closing (an internal timer); behaviour cloning without this history cannot tell "closing"
  from "closed, now lift" (the earlier probe's failures held the object and never lifted);
- optionally (``pose_window`` > 0) the last ``pose_window`` *fresh* estimates of the object
  (``pose_valid`` set and ``pose_age`` 0), summarised as their mean position and the circular
  mean of their doubled heading. One estimate is all a policy sees otherwise: under per-step
  estimation noise the expert's action is then not a function of the input, and a fit
  averages it away. The scripted controller filters its estimates
  (:class:`~scorbot_gym.policies.pose_filter.GraspPoseFilter`); this is the learned policy's
  equivalent, computed from its own observations only. With ``pose_dispersion`` the summary
  also says how much the estimates disagree (the doubled headings' resultant length, the
  positions' spread). That is off by default: the disagreement a policy sees in training is
  that of its training pose sources, and it reads any other level as a new situation, not as
  a noisier estimate of the same one (a policy trained on oracle and manifold estimates, which
  agree from step to step, met heading noise with its agreement input at ten standard
  deviations and lost most grasps; pinning that input to its training mean recovered them).

- optionally (``stall_steps`` > 0) how many steps the TCP has been still (moved under 1 mm a
  step), up to ``stall_steps``: the scripted controller closes when its descent reaches the
  grasp point *or* after 2 s of descending (another internal timer). A policy blocked on an
  object's rim, commanding down with the fingers open, otherwise sees the same input every
  step and waits for the time limit.

A few features are computed from the observation, as a feature extractor would: the object
relative to the TCP, and the object's heading relative to the base and wrist (sin/cos of twice
the angle: a parallel gripper closes along the same line after a half turn).

A saved policy is a folder: ``policy.json`` (format, ``"algo": "imitation"``,
``"uses_scripted_controller": false``, the observation entries and shapes, the history spec,
the feature normalisation, the network layout, how it was trained) and ``weights.npz`` (the
MLP's weights as plain arrays, no pickle). Inference is numpy only: loading needs no torch.
"""

from __future__ import annotations

import json
import os
import tempfile
import warnings
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from scorbot_gym.policies.object_features import (
    check_object_features,
    grasp_frame_view,
    n_object_features,
    object_name,
)
from scorbot_gym.policies.sb3 import check_action_type, read_policy_json  # one folder format
from scorbot_gym.policies.scripted import yaw_from_quat

ALGO = "imitation"
SHIPPED_LEARNED_POLICY = Path(__file__).parent / "data" / "imitation_dagger_estimates"
#: the shipped ``learned`` policy after RLPD-style SAC fine-tuning with the oracle pose
#: (scorbot_gym.rl.finetune; benchmarks/finetune.py); its ``policy.json`` records both stages
SHIPPED_FINETUNED_POLICY = Path(__file__).parent / "data" / "imitation_rlpd_oracle"
#: ``learned``'s recipe told the object's grasp frame instead of its class
#: (``object_features="grasp_frame"``): the stand-alone arm that carries to new objects
SHIPPED_GRASP_FRAME_POLICY = Path(__file__).parent / "data" / "imitation_grasp_frame"
#: ``learned_grasp_frame`` after the RLPD-style fine-tune that made ``finetuned`` from ``learned``
SHIPPED_GRASP_FRAME_FINETUNED_POLICY = Path(__file__).parent / "data" / "imitation_rlpd_grasp_frame"
#: pose_age is scaled as log1p(age) / log1p(AGE_SCALE): 0 fresh, 1 never estimated
AGE_SCALE = 1000.0
#: proprioception and pose entries the features read (besides ``object_class``)
OBSERVATION_KEYS = (
    "joint_pos",
    "joint_vel",
    "gripper_opening",
    "ee_pos",
    "ee_quat",
    "object_pos",
    "object_quat",
    "pose_valid",
    "pose_confidence",
    "pose_age",
)
#: index of the scaled ``pose_age`` in the features: 1.0 before the episode's first valid
#: estimate, when the pose entries are the wrapper's placeholders (zeros), not a pose
AGE_FEATURE = 46
#: normalised features are clipped to this many standard deviations
FEATURE_CLIP = 10.0
#: a feature whose training std is below this never varied: it is pinned to 0
CONSTANT_STD = 1e-3


@dataclass(frozen=True)
class HistorySpec:
    """How much of its own past the policy sees (see the module docstring)."""

    previous_actions: int = 2
    gripper_commands: int = 20
    pose_window: int = 0
    #: the window's summary also gives the estimates' disagreement (module docstring)
    pose_dispersion: bool = False
    #: > 0: how long the TCP has been still, counted up to this many steps (module docstring)
    stall_steps: int = 0

    def __post_init__(self) -> None:
        for name, value in asdict(self).items():
            if name == "pose_dispersion":
                if not isinstance(value, bool):
                    raise ValueError(f"history pose_dispersion must be a bool, got {value!r}")
            elif isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise ValueError(f"history {name} must be an int >= 0, got {value!r}")
        if self.pose_dispersion and not self.pose_window:
            raise ValueError("history pose_dispersion needs a pose_window > 0")

    @classmethod
    def from_record(cls, record: dict[str, Any]) -> HistorySpec:
        """The spec a ``policy.json`` (or training config) records. Records written before
        ``pose_dispersion`` existed had it whenever they had a window."""
        record = dict(record)
        if "pose_dispersion" not in record:
            record["pose_dispersion"] = bool(record.get("pose_window"))
        try:
            return cls(**record)
        except TypeError as exc:  # an unknown key
            raise ValueError(f"history {record!r}: {exc}") from None


#: a TCP that moved less than this between two observations was still (``stall_steps``)
STILL_M = 0.001
#: values summarising the window of fresh estimates (:meth:`ActionHistory.pose_features`)
N_POSE_WINDOW_FEATURES = 15
#: the window's disagreement values, with ``pose_dispersion``
N_POSE_DISPERSION_FEATURES = 2


def n_window_features(history: HistorySpec) -> int:
    """How many values :meth:`ActionHistory.pose_features` gives under ``history``."""
    if not history.pose_window:
        return 0
    return N_POSE_WINDOW_FEATURES + N_POSE_DISPERSION_FEATURES * history.pose_dispersion


def n_history_features(history: HistorySpec) -> int:
    """How many values :meth:`ActionHistory.features` gives under ``history``."""
    return 6 * history.previous_actions + history.gripper_commands + (history.stall_steps > 0)


def n_features(n_classes: int, history: HistorySpec, object_features: str = "class") -> int:
    """How many features a policy with ``n_classes`` classes, ``history`` and what it is told
    of the object (:mod:`~scorbot_gym.policies.object_features`) reads."""
    return (
        47
        + n_object_features(object_features, n_classes)
        + n_history_features(history)
        + n_window_features(history)
    )


def _fresh_estimate(obs: dict[str, np.ndarray]) -> tuple[np.ndarray, float] | None:
    """The observation's (position, heading) if it carries a new estimate, else None (a lost
    estimate, a held one between estimation steps, or the placeholder before the first)."""
    if float(obs["pose_valid"][0]) < 0.5 or float(obs["pose_age"][0]) > 0.0:
        return None
    return np.asarray(obs["object_pos"], float), yaw_from_quat(np.asarray(obs["object_quat"]))


class ActionHistory:
    """The policy's memory of the episode so far: its executed actions and, with
    ``spec.pose_window``, the fresh pose estimates it acted on."""

    def __init__(self, spec: HistorySpec, action_dim: int = 6) -> None:
        self.spec, self.action_dim = spec, action_dim
        self.reset()

    def reset(self) -> None:
        self.actions = np.zeros((self.spec.previous_actions, self.action_dim), np.float32)
        # before the first step the gripper was commanded open, as the env resets it
        self.gripper = np.ones(self.spec.gripper_commands, np.float32)
        self.estimates: list[tuple[np.ndarray, float]] = []
        self.still_steps = 0  # consecutive steps the TCP moved under STILL_M
        self._tcp: np.ndarray | None = None

    def push(self, action: np.ndarray, obs: dict[str, np.ndarray] | None = None) -> None:
        """Remember the action that was executed (whoever chose it) and the observation it was
        chosen on (needed with ``pose_window``: its estimate joins the window if fresh; and
        with ``stall_steps``: its TCP position says whether the arm moved)."""
        if (self.spec.pose_window or self.spec.stall_steps) and obs is None:
            raise ValueError(
                "a history with pose_window or stall_steps > 0 needs the observation in push"
            )
        if self.spec.pose_window:
            fresh = _fresh_estimate(obs)
            if fresh is not None:
                self.estimates = [*self.estimates, fresh][-self.spec.pose_window :]
        if self.spec.stall_steps:
            tcp = np.asarray(obs["ee_pos"], float)
            still = self._tcp is not None and np.linalg.norm(tcp - self._tcp) < STILL_M
            self.still_steps = self.still_steps + 1 if still else 0
            self._tcp = tcp
        a = np.asarray(action, np.float32)
        if self.spec.previous_actions:
            self.actions = np.roll(self.actions, 1, axis=0)
            self.actions[0] = a
        if self.spec.gripper_commands:
            self.gripper = np.roll(self.gripper, 1)
            self.gripper[0] = 1.0 if a[-1] > 0 else -1.0

    def features(self) -> np.ndarray:
        """Previous actions, gripper commands and, with ``stall_steps``, how long the TCP has
        been still (0 moving ... 1 for ``stall_steps`` steps or more; counted up to the
        observation the last action was chosen on)."""
        parts = [self.actions.ravel(), self.gripper]
        if self.spec.stall_steps:
            parts.append([min(self.still_steps, self.spec.stall_steps) / self.spec.stall_steps])
        return np.concatenate(parts).astype(np.float32)

    def pose_features(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        """The window of the last ``pose_window`` fresh estimates, ``obs``'s own included:
        fraction of the window filled, mean position, mean minus the TCP, sin/cos of the
        doubled circular-mean heading relative to base and wrist (as the single-estimate
        features); with ``pose_dispersion`` also the doubled headings' resultant length (1:
        they agree) and the positions' RMS spread. Zeros, filled fraction 0, before the first
        fresh estimate."""
        window = self.spec.pose_window
        if not window:
            return np.zeros(0, np.float32)
        fresh = _fresh_estimate(obs)
        estimates = [*self.estimates, *([fresh] if fresh is not None else [])][-window:]
        if not estimates:
            return np.zeros(n_window_features(self.spec), np.float32)
        pos = np.array([p for p, _ in estimates])
        yaws = np.array([y for _, y in estimates])
        mean = pos.mean(axis=0)
        c, s = np.cos(2 * yaws).mean(), np.sin(2 * yaws).mean()
        yaw = 0.5 * np.arctan2(s, c)
        q = np.asarray(obs["joint_pos"], float)
        angles = np.array([yaw, yaw - q[0], yaw - q[0] - q[4], yaw - q[0] + q[4]])
        parts = [
            [len(estimates) / window],
            mean,
            mean - np.asarray(obs["ee_pos"], float),
            np.sin(2 * angles),
            np.cos(2 * angles),
        ]
        if self.spec.pose_dispersion:
            spread = np.sqrt(np.mean(np.sum((pos - mean) ** 2, axis=1)))
            parts.append([np.hypot(c, s), spread])
        return np.concatenate(parts).astype(np.float32)


def observation_features(obs: dict[str, np.ndarray], onehot: np.ndarray) -> np.ndarray:
    """The observation part of the features: 47 values, then ``onehot`` (the class one-hot;
    empty for a grasp-frame policy, whose pose entries already are the object's grasp frame)."""
    q = np.asarray(obs["joint_pos"], float)
    ee = np.asarray(obs["ee_pos"], float)
    pos = np.asarray(obs["object_pos"], float)
    yaw = yaw_from_quat(np.asarray(obs["object_quat"], float))
    angles = np.array([yaw, yaw - q[0], yaw - q[0] - q[4], yaw - q[0] + q[4]])
    age = np.log1p(float(obs["pose_age"][0])) / np.log1p(AGE_SCALE)
    return np.concatenate(
        [
            q,
            np.asarray(obs["joint_vel"], float),
            np.asarray(obs["gripper_opening"], float),
            ee,
            np.asarray(obs["ee_quat"], float),
            pos,
            np.asarray(obs["object_quat"], float),
            pos - ee,
            np.sin(angles),
            np.cos(angles),
            np.sin(2 * angles),
            np.cos(2 * angles),
            np.asarray(obs["pose_valid"], float),
            np.asarray(obs["pose_confidence"], float),
            [age],
            np.asarray(onehot, float),
        ]
    ).astype(np.float32)


class MLP:
    """ReLU MLP in numpy; the last layer gives 5 arm outputs (tanh) and 1 gripper logit."""

    def __init__(self, weights: Sequence[np.ndarray], biases: Sequence[np.ndarray]) -> None:
        self.weights = [np.asarray(w, np.float32) for w in weights]
        self.biases = [np.asarray(b, np.float32) for b in biases]

    def __call__(self, x: np.ndarray) -> np.ndarray:
        h = np.asarray(x, np.float32)
        for i, (w, b) in enumerate(zip(self.weights, self.biases, strict=True)):
            h = h @ w + b
            if i < len(self.weights) - 1:
                h = np.maximum(h, 0.0)
        return h

    @property
    def n_inputs(self) -> int:
        return self.weights[0].shape[0]


def to_action(raw: np.ndarray) -> np.ndarray:
    """Network output → env action: arm in (-1, 1) by tanh, gripper ±1 by the logit's sign
    (the demonstrations' gripper is binary; a half-open command would drop the object)."""
    raw = np.asarray(raw, np.float32)
    arm = np.tanh(raw[..., :-1])
    grip = np.where(raw[..., -1:] > 0, 1.0, -1.0).astype(np.float32)
    return np.concatenate([arm, grip], axis=-1).astype(np.float32)


def open_policy_folder(path: str | Path, algo: str) -> tuple[Path, Path, dict[str, Any]]:
    """``policy.json`` (which must say ``algo``) and ``weights.npz`` of a numpy policy folder:
    their paths and the metadata; a missing or mismatched file is a one-line error."""
    path = Path(path)
    if not path.is_dir():
        raise FileNotFoundError(
            f"no policy folder at {path} (expected policy.json and weights.npz)"
        )
    meta_path, weights_path = path / "policy.json", path / "weights.npz"
    for p in (meta_path, weights_path):
        if not p.is_file():
            raise FileNotFoundError(f"policy {path} is missing {p.name}")
    meta = read_policy_json(meta_path)
    if meta.get("algo") != algo:
        raise ValueError(f"{meta_path}: algo must be {algo!r}, got {meta.get('algo')!r}")
    check_numpy_policy_fields(meta_path, meta)
    return meta_path, weights_path, meta


def check_numpy_policy_fields(meta_path: Path, meta: dict[str, Any]) -> None:
    """The fields of a numpy policy's ``policy.json`` that loading and acting read, checked for
    type: a damaged field is a one-line error naming it and what it must hold, instead of
    numpy's "could not convert string to float" or "operands could not be broadcast" later."""

    def bad(field: str, what: str, value: Any) -> ValueError:
        shown = repr(value)
        shown = shown if len(shown) <= 60 else shown[:57] + "..."
        return ValueError(f"{meta_path}: {field} must be {what}, got {shown}")

    norm = meta.get("normalization")
    if not isinstance(norm, dict):
        raise bad("normalization", 'an object {"mean": [...], "std": [...]}', norm)
    for key in ("mean", "std"):
        v = norm.get(key)
        if not (isinstance(v, list) and v and all(_is_number(x) for x in v)):
            raise bad(f"normalization.{key}", "a non-empty list of finite numbers", v)
    mean, std = norm["mean"], norm["std"]
    if len(mean) != len(std):
        raise ValueError(
            f"{meta_path}: normalization.mean has {len(mean)} numbers and normalization.std "
            f"{len(std)}: they must have one per feature each"
        )
    if min(std) < 0:
        raise bad("normalization.std", "numbers >= 0", min(std))
    if not isinstance(meta.get("history"), dict):
        raise bad("history", 'an object such as {"previous_actions": 2, ...}', meta.get("history"))
    classes = meta.get("classes")
    if not (isinstance(classes, list) and all(isinstance(c, str) for c in classes)):
        raise bad("classes", "a list of object names", classes)
    if meta.get("action_type") not in ("joint", "cartesian"):
        raise bad("action_type", "'joint' or 'cartesian'", meta.get("action_type"))
    try:
        check_object_features(meta.get("object_features", "class"))
    except ValueError:
        raise bad("object_features", "'class' or 'grasp_frame'", meta["object_features"]) from None
    shapes = meta.get("observation_shapes", {})
    if not (
        isinstance(shapes, dict)
        and all(
            isinstance(v, list) and all(isinstance(n, int) and n >= 0 for n in v)
            for v in shapes.values()
        )
    ):
        raise bad("observation_shapes", "an object of entry name -> list of sizes", shapes)


def _is_number(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and np.isfinite(x)


class ImitationPolicy:
    """The learned policy: features of (observation, own action history) → MLP → action.

    ``meta`` is the content of ``policy.json``; ``mean``/``std`` normalise the features.
    """

    uses_scripted_controller = False

    def __init__(self, net: MLP, mean: np.ndarray, std: np.ndarray, meta: dict[str, Any]) -> None:
        self.net, self.meta = net, meta
        self.mean = np.asarray(mean, np.float32)
        self.std = np.asarray(std, np.float32)
        self.history_spec = HistorySpec.from_record(meta["history"])
        self.classes = tuple(meta["classes"])
        #: what the network is told of the object besides its pose (policies saved before
        #: this key existed were told the class)
        self.object_features = meta.get("object_features", "class")
        self.history = ActionHistory(self.history_spec)
        self._env_classes: tuple[str, ...] | None = None
        #: steps since load on which a grasp-frame policy read the object's own pose instead
        #: of its grasp frame (an estimate without an identity; see :meth:`view`)
        self.frame_fallbacks = 0
        want = n_features(len(self.classes), self.history_spec, self.object_features)
        if not (len(self.mean) == len(self.std) == net.n_inputs == want):
            raise ValueError(
                f"incompatible policy: {want} features from policy.json, normalisation has "
                f"{len(self.mean)}, the network takes {net.n_inputs}"
            )

    # --- features --------------------------------------------------------------------------
    def _onehot(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        if "object_class" not in obs:
            return np.zeros(len(self.classes))
        onehot = np.asarray(obs["object_class"], float)
        if self._env_classes is None:
            return onehot
        out = np.zeros(len(self.classes))
        for name, v in zip(self._env_classes, onehot, strict=True):
            if name in self.classes:
                out[self.classes.index(name)] = v
        return out

    def view(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """The observation as the network reads it: as it is, or with ``object_features=
        "grasp_frame"`` the object's pose replaced by its grasp frame
        (:mod:`~scorbot_gym.policies.object_features`)."""
        if self.object_features == "class":
            return obs
        name = object_name(obs, self._env_classes or self.classes)
        if name is None and np.any(obs["object_quat"]):
            # An estimate with no identity (an unrecognised object): there is no mesh to derive
            # the frame from, so the network reads the object's own pose in its place, which
            # it was not trained on. Said once, and counted, rather than done silently.
            if not self.frame_fallbacks:
                warnings.warn(
                    "the observation has an object pose but no identity: this grasp-frame "
                    "policy reads the object's own pose in place of its grasp frame",
                    RuntimeWarning,
                    stacklevel=2,
                )
            self.frame_fallbacks += 1
        return grasp_frame_view(obs, name)

    def features(self, obs: dict[str, np.ndarray], history: ActionHistory) -> np.ndarray:
        """Raw (unnormalised) features of an observation with a given history."""
        return self._features_of_view(self.view(obs), history)

    def _features_of_view(self, view: dict[str, np.ndarray], history: ActionHistory) -> np.ndarray:
        onehot = self._onehot(view) if self.object_features == "class" else np.zeros(0)
        return np.r_[
            observation_features(view, onehot),
            history.features(),
            history.pose_features(view),
        ]

    def remember(
        self, history: ActionHistory, action: np.ndarray, obs: dict[str, np.ndarray]
    ) -> None:
        """``history.push`` of the action chosen on ``obs``, as the network reads ``obs``
        (its window of fresh estimates holds grasp frames under ``"grasp_frame"``)."""
        history.push(action, self.view(obs))

    def normalise(self, feats: np.ndarray) -> np.ndarray:
        z = (feats - self.mean) / np.maximum(self.std, CONSTANT_STD)
        z = np.where(self.std < CONSTANT_STD, 0.0, z)
        return np.clip(z, -FEATURE_CLIP, FEATURE_CLIP).astype(np.float32)

    def action_from_features(self, feats: np.ndarray) -> np.ndarray:
        return to_action(self.net(self.normalise(feats)))

    # --- Policy protocol -------------------------------------------------------------------
    def reset(self, obs: dict[str, np.ndarray], info: dict[str, Any] | None = None) -> None:
        self.history.reset()

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        view = self.view(obs)
        action = self.action_from_features(self._features_of_view(view, self.history))
        self.history.push(action, view)
        return action

    replans = 0  # the episode runner's replan count: a learned policy does not plan

    # --- env matching ----------------------------------------------------------------------
    def bind(self, env) -> ImitationPolicy:
        """Check that ``env`` gives what the policy reads and takes its actions; remember the
        env's class names so that its ``object_class`` one-hot is re-ordered into the
        policy's. Returns ``self``."""
        check_action_type(env, self.meta["action_type"])
        have = {k: tuple(s.shape) for k, s in env.observation_space.spaces.items()}
        want = {k: tuple(v) for k, v in self.meta["observation_shapes"].items()}
        wrong = {
            k: have.get(k) for k, v in want.items() if k != "object_class" and have.get(k) != v
        }
        if wrong:
            raise ValueError(
                f"wrong observation space for this policy: it reads {want}, the env gives "
                f"{wrong} for those entries (wrap the env with PoseEstimateObservation, "
                "rotation='quat')"
            )
        self._env_classes = None
        if "object_class" in have:
            names = tuple(env.get_wrapper_attr("class_names"))
            self._env_classes = names if names != self.classes else None
        elif self.object_features == "grasp_frame":
            raise ValueError(
                "this policy reads the object's grasp frame, which needs its identity: wrap the "
                "env with PoseEstimateObservation(include_class=True)"
            )
        return self

    def env_kwargs(self) -> dict[str, Any]:
        """Keywords for :func:`scorbot_gym.make_env` that give this policy its observations."""
        cartesian = self.meta["action_type"] == "cartesian"
        env_id = "ScorbotGraspCartesian-v0" if cartesian else "ScorbotGrasp-v0"
        if self.object_features == "grasp_frame":
            # the identity only picks the mesh, so the one-hot covers the env's own objects
            # (pinned to the training classes, an object outside them would have no identity,
            # and no grasp frame)
            return {"env_id": env_id}
        return {"env_id": env_id, "classes": list(self.classes)}

    # --- files -----------------------------------------------------------------------------
    def save(self, path: str | Path) -> Path:
        """Write ``policy.json`` and ``weights.npz`` into the folder ``path`` (atomically)."""
        path = Path(path)
        path.mkdir(parents=True, exist_ok=True)
        meta = {
            **self.meta,
            "normalization": {"mean": self.mean.tolist(), "std": self.std.tolist()},
        }
        arrays = {f"w{i}": w for i, w in enumerate(self.net.weights)}
        arrays.update({f"b{i}": b for i, b in enumerate(self.net.biases)})
        _atomic(path / "weights.npz", lambda f: np.savez(f, **arrays))
        _atomic(path / "policy.json", lambda f: f.write(json.dumps(meta, indent=2).encode()))
        return path

    @classmethod
    def load(cls, path: str | Path) -> ImitationPolicy:
        """A policy folder; a missing, corrupt or incompatible file is a one-line error."""
        meta_path, weights_path, meta = open_policy_folder(path, ALGO)
        try:
            norm = meta["normalization"]
            mean, std = np.asarray(norm["mean"], float), np.asarray(norm["std"], float)
            HistorySpec.from_record(meta["history"])
            meta["classes"], meta["action_type"], meta["observation_shapes"]
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"{meta_path} is incomplete or malformed ({exc!r})") from None
        try:
            with np.load(weights_path, allow_pickle=False) as z:
                n = sum(1 for k in z.files if k.startswith("w"))
                weights = [z[f"w{i}"] for i in range(n)]
                biases = [z[f"b{i}"] for i in range(n)]
        except Exception as exc:  # numpy raises many kinds on a damaged archive
            raise ValueError(
                f"{weights_path} could not be read as policy weights: {type(exc).__name__}: {exc}"
            ) from None
        if (
            not weights
            or any(
                w.ndim != 2 or b.shape != (w.shape[1],)
                for w, b in zip(weights, biases, strict=True)
            )
            or any(a.shape[0] != w.shape[1] for w, a in zip(weights, weights[1:], strict=False))
        ):
            raise ValueError(f"{weights_path}: the layers' shapes do not chain into an MLP")
        if weights[-1].shape[1] != 6:
            raise ValueError(
                f"{weights_path}: the network has {weights[-1].shape[1]} outputs, not 6"
            )
        try:
            return cls(MLP(weights, biases), mean, std, meta)
        except ValueError as exc:
            raise ValueError(f"{path}: {exc}") from None


def _atomic(path: Path, write) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
        os.chmod(tmp, 0o644)  # mkstemp makes it private; a policy file is package data
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
