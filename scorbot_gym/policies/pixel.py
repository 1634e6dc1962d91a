"""A stand-alone grasping policy from pixels: the imitation recipe with no pose estimator.

The end-to-end arm against which the pose-manifold pipeline is judged. The policy sees

- the RGB image of **each of its cameras** (``top`` by default; ``top`` and the wrist camera
  ``eye_in_hand`` as robomimic's image policies see the scene and the gripper), downsized to
  ``frame_size`` x ``frame_size`` (84 by default, area interpolation; whatever size the env
  renders, so the policy also runs on the 320x240 frames a pose source reads, though it was
  trained on the size its ``policy.json`` names), with the last ``frame_stack`` frames of each
  stacked (DrQ's memory: the object, hidden by the arm for most of an approach, is still in an
  earlier frame; :class:`FrameHistory` keeps them);
- **proprioception** (joint angles and velocities, gripper opening, TCP position and quaternion);
- the **target class** one-hot (``object_class`` from the pose wrapper with the identity given,
  or the cluttered env's ``target_class``; zeros where the env gives neither): the same task
  command the state policy gets;
- the same **executed-action history** as the state policy
  (:class:`~scorbot_gym.policies.imitation.ActionHistory`: previous actions and the
  gripper-command history that stands in for the scripted controller's lift timer).

It never reads ``object_pos``, ``object_quat``, ``pose_valid``, ``pose_confidence`` or
``pose_age`` (:data:`POSE_KEYS`): where the object is, and how it is turned, has to come from
the image. The network has one image encoder per camera (:class:`NetSpec` names it: the
Nature-DQN stack of Mnih et al. 2015, or a spatial-softmax keypoint encoder) whose 256-unit
embeddings are concatenated with the normalised proprioceptive features and passed through a
256-unit MLP to the same outputs as the state policy: 5 arm values (tanh) and 1 gripper
logit (sign).

A saved policy is a folder: ``policy.json`` (``"algo": "pixel_imitation"``,
``"observation": "pixels"``, ``"uses_scripted_controller": false``, the cameras, frame size,
history, normalisation, network layout and how it was trained) and ``weights.npz`` (the
network's tensors as plain arrays, no pickle). Inference runs on the CPU with torch.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from scorbot_gym.policies.imitation import (
    CONSTANT_STD,
    FEATURE_CLIP,
    ActionHistory,
    HistorySpec,
    _atomic,
    n_history_features,
    open_policy_folder,
    to_action,
)
from scorbot_gym.policies.sb3 import FORMAT, VERSION, check_action_type

ALGO = "pixel_imitation"
#: proprioception the features read, in this order
PROPRIO_KEYS = ("joint_pos", "joint_vel", "gripper_opening", "ee_pos", "ee_quat")
PROPRIO_SIZE = 18
#: what a pose estimator adds to the observation: the pixel policy never reads these
POSE_KEYS = ("object_pos", "object_quat", "object_yaw", "pose_valid", "pose_confidence", "pose_age")
#: the 4:3 size the top camera renders at for training: its whole field, 84 rows
DEFAULT_RENDER_SIZE = (112, 84)


#: the image encoders a :class:`NetSpec` can name (``policy.json`` records which one)
ENCODERS = ("nature", "spatial_softmax")


@dataclass(frozen=True)
class NetSpec:
    """The network's layout (recorded in ``policy.json``; the weights must match it).

    ``encoder`` swaps the image encoder, the rest of the network staying the same:

    - ``"nature"``: the Nature-DQN stack (strides 4 and 2), flattened: a global code, coarse
      in position (one cell of its last map spans ~8 px, ~8 cm on the table);
    - ``"spatial_softmax"``: a stride-2 stack kept at 36 x 36 (for 84 px), then one softmax
      over each of ``keypoints`` feature maps and its expected image coordinates (Levine et
      al. 2016, "End-to-end training of deep visuomotor policies"; robomimic's default): the
      code is *where* things are, at sub-pixel resolution, what a grasp needs.
    """

    frame_size: int = 84
    channels: int = 3  # 3: RGB, 1: grayscale
    #: frames of each camera the network sees, the newest last (1: the current one only)
    frame_stack: int = 1
    #: cameras, each with its own encoder and embedding (``policy.json`` names them)
    cameras: int = 1
    embedding: int = 256
    hidden: int = 256
    encoder: str = "nature"
    keypoints: int = 32  # spatial_softmax only

    def __post_init__(self) -> None:
        if self.encoder not in ENCODERS:
            raise ValueError(f"encoder must be one of {ENCODERS}, got {self.encoder!r}")
        if self.frame_size < 36:  # the convolutions need at least 36 pixels
            raise ValueError(f"frame_size must be >= 36, got {self.frame_size}")
        if self.channels not in (1, 3):
            raise ValueError(f"channels must be 1 (grayscale) or 3 (RGB), got {self.channels}")
        for name in ("embedding", "hidden", "keypoints", "frame_stack", "cameras"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")

    @classmethod
    def from_record(cls, record: dict[str, Any]) -> NetSpec:
        """The spec a ``policy.json`` ``network`` entry names (files written before the
        ``encoder`` field existed used the Nature encoder)."""
        encoder = str(record.get("encoder", "nature"))
        if encoder.startswith("Nature-DQN"):  # early files kept a description under that key
            encoder = "nature"
        return cls(
            frame_size=int(record["frame_size"]),
            channels=int(record["channels"]),
            embedding=int(record["embedding"]),
            hidden=int(record["hidden"]),
            encoder=encoder,
            keypoints=int(record.get("keypoints", 32)),
            frame_stack=int(record.get("frame_stack", 1)),
            cameras=int(record.get("cameras", 1)),
        )


def build_network(spec: NetSpec, n_vector: int):
    """The torch module: a CNN embedding per camera (of its stacked frames) ⊕ vector features
    → MLP → 6 outputs. The first camera's modules keep the names (``encoder``, ``embed``) that
    single-camera files were written with; camera ``i`` > 0 has ``encoder{i}``, ``embed{i}``."""
    import torch as th
    from torch import nn

    class SpatialSoftmax(nn.Module):
        """(B, C, H, W) feature maps → (B, 2K): the expected (x, y) in [-1, 1] of each of K
        learned keypoint maps under a softmax with a learned temperature."""

        def __init__(self, channels: int, height: int, width: int, keypoints: int) -> None:
            super().__init__()
            self.project = nn.Conv2d(channels, keypoints, 1)
            self.log_temperature = nn.Parameter(th.zeros(1))
            gy, gx = th.meshgrid(
                th.linspace(-1.0, 1.0, height), th.linspace(-1.0, 1.0, width), indexing="ij"
            )
            grid = th.stack([gx.reshape(-1), gy.reshape(-1)], dim=1)
            self.register_buffer("grid", grid, persistent=False)  # rebuilt, never saved

        def forward(self, x: th.Tensor) -> th.Tensor:
            logits = self.project(x).flatten(2) / self.log_temperature.exp()
            return (th.softmax(logits, dim=-1) @ self.grid).flatten(1)

    per_camera = spec.frame_stack * spec.channels

    def convs(layers: list[tuple[int, int, int]]) -> list[nn.Module]:
        """Conv2d + ReLU per (channels out, kernel, stride), from one camera's channels."""
        out, c = [], per_camera
        for n, k, stride in layers:
            out += [nn.Conv2d(c, n, k, stride=stride), nn.ReLU()]
            c = n
        return out

    def encoder() -> nn.Module:
        if spec.encoder == "nature":
            return nn.Sequential(*convs([(32, 8, 4), (64, 4, 2), (64, 3, 1)]), nn.Flatten())
        trunk = nn.Sequential(*convs([(32, 5, 2), (32, 3, 1), (32, 3, 1)]))
        with th.no_grad():
            frame = th.zeros(1, per_camera, spec.frame_size, spec.frame_size)
            _, n, h, w = trunk(frame).shape
        return nn.Sequential(trunk, SpatialSoftmax(n, h, w, spec.keypoints))

    class PixelNet(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.names = [("encoder", "embed")] + [
                (f"encoder{i}", f"embed{i}") for i in range(1, spec.cameras)
            ]
            for enc_name, embed_name in self.names:
                enc = encoder()
                with th.no_grad():
                    size = spec.frame_size
                    n_flat = enc(th.zeros(1, per_camera, size, size)).shape[1]
                setattr(self, enc_name, enc)
                setattr(
                    self, embed_name, nn.Sequential(nn.Linear(n_flat, spec.embedding), nn.ReLU())
                )
            self.head = nn.Sequential(
                nn.Linear(spec.cameras * spec.embedding + n_vector, spec.hidden),
                nn.ReLU(),
                nn.Linear(spec.hidden, spec.hidden),
                nn.ReLU(),
                nn.Linear(spec.hidden, 6),
            )

        def forward(self, frames: th.Tensor, vectors: th.Tensor) -> th.Tensor:
            """``frames`` uint8 (B, cameras x stack x C, H, W) or float in [0, 1], camera-major
            (:func:`stack_frames`); ``vectors`` normalised."""
            x = frames.float() / 255.0 if frames.dtype == th.uint8 else frames
            parts = th.split(x, per_camera, dim=1)
            codes = [
                getattr(self, embed)(getattr(self, enc)(part))
                for (enc, embed), part in zip(self.names, parts, strict=True)
            ]
            return self.head(th.cat([*codes, vectors], dim=1))

    return PixelNet()


def stack_frames(frames, cameras: int):
    """Frames (..., K, cameras x C, S, S), the oldest first (numpy or torch), as the network's
    input (..., cameras x K x C, S, S): each camera's K frames side by side in its own group of
    channels, the group its encoder reads."""
    *lead, k, cc, h, w = frames.shape
    c = cc // cameras
    x = frames.reshape(*lead, k, cameras, c, h, w)
    n = len(lead)
    order = (*range(n), n + 1, n, n + 2, n + 3, n + 4)
    x = x.transpose(order) if isinstance(x, np.ndarray) else x.permute(*order)
    return x.reshape(*lead, cameras * k * c, h, w)


class FrameHistory(ActionHistory):
    """:class:`~scorbot_gym.policies.imitation.ActionHistory` plus the frames the policy saw:
    the last ``frame_stack - 1`` (each camera's, as :meth:`PixelPolicy.current_frames` gives
    them), pushed with the action chosen on them."""

    def __init__(self, spec: HistorySpec, policy: PixelPolicy) -> None:
        self.policy = policy
        super().__init__(spec)

    def reset(self) -> None:
        super().reset()
        self.frames: list[np.ndarray] = []
        self._seen: tuple[dict, np.ndarray] | None = None

    def push(self, action: np.ndarray, obs: dict[str, np.ndarray] | None = None) -> None:
        super().push(action, obs)
        keep = self.policy.net_spec.frame_stack - 1
        if keep:
            if obs is None:
                raise ValueError("a frame stack needs the observation in push")
            seen = self._seen
            # the frames stacked() was given for this very observation, else computed again
            frames = seen[1] if seen is not None and seen[0] is obs else None
            if frames is None:
                frames = self.policy.current_frames(obs)
            self.frames = [*self.frames, frames][-keep:]
        self._seen = None

    def stacked(self, current: np.ndarray, obs: dict | None = None) -> np.ndarray:
        """The last ``frame_stack`` frames, ``current`` the newest; before the episode has
        that many, its first frame repeated (as Gymnasium's ``FrameStackObservation`` pads
        with the reset's). ``current`` is kept for the ``push`` of the same ``obs`` (the
        frames are resized once per step, not again when they are stored)."""
        k = self.policy.net_spec.frame_stack
        self._seen = (obs, current) if obs is not None else None
        seen = [*self.frames, current][-k:]
        return np.stack([seen[0]] * (k - len(seen)) + seen)


def to_frame(image: np.ndarray, spec: NetSpec) -> np.ndarray:
    """An H x W x 3 uint8 camera image as the network's (C, S, S) uint8 frame."""
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[-1] != 3:
        raise ValueError(f"expected an H x W x 3 RGB image, got shape {img.shape}")
    s = spec.frame_size
    if img.shape[:2] != (s, s):
        img = cv2.resize(img, (s, s), interpolation=cv2.INTER_AREA)
    if spec.channels == 1:
        return cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)[None]
    return np.ascontiguousarray(img.transpose(2, 0, 1))


class PixelPolicy:
    """Camera frames + proprioception + class + own action history → CNN/MLP → action.

    ``features(obs, history)`` gives ``(frame, vector)``: the same duck type as
    :class:`~scorbot_gym.policies.imitation.ImitationPolicy`, so the imitation trainer's
    collection and DAgger loops (:mod:`scorbot_gym.rl.imitation`) drive it unchanged.
    """

    uses_scripted_controller = False
    replans = 0  # the episode runner's replan count: a learned policy does not plan

    def __init__(
        self,
        net_spec: NetSpec,
        state: dict[str, np.ndarray] | None,
        mean: np.ndarray,
        std: np.ndarray,
        meta: dict[str, Any],
    ) -> None:
        import torch as th

        self.net_spec, self.meta = net_spec, meta
        self.cameras = tuple(str(c) for c in meta.get("cameras") or [meta["camera"]])
        self.camera = self.cameras[0]
        self.image_keys = tuple(f"{c}_rgb" for c in self.cameras)
        self.image_key = self.image_keys[0]
        if len(self.cameras) != net_spec.cameras:
            raise ValueError(
                f"incompatible policy: {len(self.cameras)} cameras {list(self.cameras)}, the "
                f"network reads {net_spec.cameras}"
            )
        self.classes = tuple(meta["classes"])
        self.history_spec = HistorySpec.from_record(meta["history"])
        if self.history_spec.pose_window:
            raise ValueError("a pixel policy reads no pose estimate: its pose_window must be 0")
        self.history = self.new_history()
        self.n_vector = n_vector_features(len(self.classes), self.history_spec)
        self.mean = np.asarray(mean, np.float32)
        self.std = np.asarray(std, np.float32)
        if not len(self.mean) == len(self.std) == self.n_vector:
            raise ValueError(
                f"incompatible policy: {self.n_vector} vector features from policy.json, the "
                f"normalisation has {len(self.mean)}"
            )
        self.net = build_network(net_spec, self.n_vector).eval()
        if state is not None:
            self.load_state(state)
        self._env_classes: tuple[str, ...] | None = None
        self._th = th

    def load_state(self, state: dict[str, np.ndarray]) -> None:
        """Copy weights (numpy arrays by parameter name) into the network; a missing,
        unexpected or misshapen tensor is a ValueError."""
        import torch as th

        own = self.net.state_dict()
        if set(state) != set(own):
            missing, extra = sorted(set(own) - set(state)), sorted(set(state) - set(own))
            raise ValueError(f"weights do not fit the network: missing {missing}, extra {extra}")
        bad = [k for k, v in own.items() if tuple(state[k].shape) != tuple(v.shape)]
        if bad:
            raise ValueError(f"weights do not fit the network: wrong shapes for {bad}")
        self.net.load_state_dict({k: th.as_tensor(np.asarray(v)) for k, v in state.items()})

    def state_arrays(self) -> dict[str, np.ndarray]:
        return {k: v.detach().cpu().numpy().copy() for k, v in self.net.state_dict().items()}

    # --- features --------------------------------------------------------------------------
    def _onehot(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        key = "object_class" if "object_class" in obs else "target_class"
        if key not in obs:
            return np.zeros(len(self.classes))
        onehot = np.asarray(obs[key], float)
        if self._env_classes is None:
            return onehot
        out = np.zeros(len(self.classes))
        for name, v in zip(self._env_classes, onehot, strict=True):
            if name in self.classes:
                out[self.classes.index(name)] = v
        return out

    def compact_observation(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Only what the policy reads, the image already as its small frame (H x W x C uint8):
        what the trainer stores per step (84 x 84 x 3 bytes instead of the rendered image)."""
        out = {k: np.asarray(obs[k]) for k in PROPRIO_KEYS}
        for key in ("object_class", "target_class"):
            if key in obs:
                out[key] = np.asarray(obs[key])
        s = self.net_spec.frame_size
        for key in self.image_keys:
            img = np.asarray(obs[key])
            if img.shape[:2] != (s, s):  # the same resize as to_frame: features are unchanged
                img = cv2.resize(img, (s, s), interpolation=cv2.INTER_AREA)
            out[key] = img
        return out

    def new_history(self) -> FrameHistory:
        """The per-episode memory the features read: executed actions and recent frames
        (the trainers' collection loops ask the learner for it)."""
        return FrameHistory(self.history_spec, self)

    def current_frames(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        """This step's frame of every camera, (cameras x C, S, S) uint8."""
        missing = [k for k in self.image_keys if k not in obs]
        if missing:
            raise KeyError(
                f"the pixel policy reads {missing}: make the env with "
                f"cameras={list(self.cameras)} (policy.env_kwargs() gives the settings)"
            )
        return np.concatenate([to_frame(obs[k], self.net_spec) for k in self.image_keys])

    def vector_features(self, obs: dict[str, np.ndarray], history: ActionHistory) -> np.ndarray:
        """The raw (unnormalised) vector: proprioception, class one-hot, action history."""
        return np.concatenate(
            [np.asarray(obs[k], np.float32).ravel() for k in PROPRIO_KEYS]
            + [self._onehot(obs).astype(np.float32), history.features()]
        )

    def features(
        self, obs: dict[str, np.ndarray], history: ActionHistory
    ) -> tuple[np.ndarray, np.ndarray]:
        """``(frames, vector)``: the network's uint8 image input (cameras x stack x C, S, S;
        with a frame stack, ``history`` must be this policy's :meth:`new_history`) and the
        raw vector. No pose key is read."""
        current = self.current_frames(obs)
        if self.net_spec.frame_stack > 1:
            if not isinstance(history, FrameHistory):
                raise TypeError("a frame-stacking policy needs its own new_history()")
            current = stack_frames(history.stacked(current, obs), self.net_spec.cameras)
        return current, self.vector_features(obs, history)

    def normalise(self, vectors: np.ndarray) -> np.ndarray:
        z = (vectors - self.mean) / np.maximum(self.std, CONSTANT_STD)
        z = np.where(self.std < CONSTANT_STD, 0.0, z)
        return np.clip(z, -FEATURE_CLIP, FEATURE_CLIP).astype(np.float32)

    def raw_outputs(self, frames: np.ndarray, vectors: np.ndarray) -> np.ndarray:
        """Network outputs for a batch (frames uint8 (B, C, S, S), raw vectors (B, n))."""
        th = self._th
        with th.no_grad():
            out = self.net(th.as_tensor(frames), th.as_tensor(self.normalise(vectors)))
        return out.numpy()

    def action_from_features(self, feats: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        frame, vector = feats
        return to_action(self.raw_outputs(frame[None], vector[None])[0])

    # --- Policy protocol -------------------------------------------------------------------
    def reset(self, obs: dict[str, np.ndarray], info: dict[str, Any] | None = None) -> None:
        self.history.reset()

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        action = self.action_from_features(self.features(obs, self.history))
        self.history.push(action, obs)
        return action

    def remember(
        self, history: ActionHistory, action: np.ndarray, obs: dict[str, np.ndarray]
    ) -> None:
        """``history.push`` of the action chosen on ``obs`` (the trainers' one call for every
        learner; the pixel policy reads the observation as it is)."""
        history.push(action, obs)

    # --- env matching ----------------------------------------------------------------------
    def bind(self, env) -> PixelPolicy:
        """Check that ``env`` renders the camera and gives the proprioception the policy
        reads and takes its actions; remember the env's class order. Returns ``self``."""
        check_action_type(env, self.meta["action_type"])
        have = env.observation_space.spaces
        missing = [k for k in (*PROPRIO_KEYS, *self.image_keys) if k not in have]
        if missing:
            raise ValueError(
                f"the pixel policy reads {missing}, which the env does not give: make it with "
                f"{self.env_kwargs()}"
            )
        for key in self.image_keys:
            shape = tuple(have[key].shape)
            if len(shape) != 3 or shape[-1] != 3:
                raise ValueError(f"{key} must be an H x W x 3 image, the env gives {shape}")
        self._env_classes = None
        if "object_class" in have or "target_class" in have:
            attr = "class_names" if "object_class" in have else "target_classes"
            names = tuple(env.get_wrapper_attr(attr))
            self._env_classes = names if names != self.classes else None
        return self

    def env_kwargs(self) -> dict[str, Any]:
        """Keywords for :func:`scorbot_gym.make_env` that give this policy its observations:
        the cameras it was trained on, rendered at the training size."""
        cartesian = self.meta["action_type"] == "cartesian"
        return {
            "env_id": "ScorbotGraspCartesian-v0" if cartesian else "ScorbotGrasp-v0",
            "classes": list(self.classes),
            **self.env_requirements,
        }

    @property
    def env_requirements(self) -> dict[str, Any]:
        """The env settings the policy needs (as a pose source's ``env_requirements``)."""
        width, height = self.meta["render_size"]
        return {"cameras": list(self.cameras), "image_width": width, "image_height": height}

    # --- files -----------------------------------------------------------------------------
    def save(self, path: str | Path) -> Path:
        """Write ``policy.json`` and ``weights.npz`` into the folder ``path`` (atomically)."""
        path = Path(path)
        path.mkdir(parents=True, exist_ok=True)
        meta = {
            **self.meta,
            "network": {**self.meta.get("network", {}), **self.net_spec.__dict__},
            "normalization": {"mean": self.mean.tolist(), "std": self.std.tolist()},
        }
        arrays = {k: v.astype(np.float32) for k, v in self.state_arrays().items()}
        _atomic(path / "weights.npz", lambda f: np.savez_compressed(f, **arrays))
        _atomic(path / "policy.json", lambda f: f.write(json.dumps(meta, indent=2).encode()))
        return path

    @classmethod
    def load(cls, path: str | Path) -> PixelPolicy:
        """A policy folder; a missing, corrupt or incompatible file is a one-line error."""
        meta_path, weights_path, meta = open_policy_folder(path, ALGO)
        try:
            norm = meta["normalization"]
            mean, std = np.asarray(norm["mean"], float), np.asarray(norm["std"], float)
            spec = NetSpec.from_record(meta["network"])
            HistorySpec.from_record(meta["history"])
            meta["classes"], meta["action_type"], meta.get("cameras") or meta["camera"]
            width, height = meta["render_size"]
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"{meta_path} is incomplete or malformed ({exc!r})") from None
        try:
            with np.load(weights_path, allow_pickle=False) as z:
                state = {k: z[k] for k in z.files}
        except Exception as exc:  # numpy and zipfile raise many kinds on a damaged archive
            raise ValueError(
                f"{weights_path} could not be read as policy weights: {type(exc).__name__}: {exc}"
            ) from None
        try:
            return cls(spec, state, mean, std, meta)
        except ValueError as exc:
            raise ValueError(f"{path}: {exc}") from None


def n_vector_features(n_classes: int, history: HistorySpec) -> int:
    return PROPRIO_SIZE + n_classes + n_history_features(history)


def new_meta(
    *,
    classes: tuple[str, ...],
    action_type: str,
    cameras: tuple[str, ...] | list[str],
    render_size: tuple[int, int],
    history: HistorySpec,
) -> dict[str, Any]:
    """``policy.json`` of an untrained pixel policy (the trainer adds how it was trained)."""
    cameras = [str(c) for c in cameras]
    from dataclasses import asdict

    return {
        "format": FORMAT,
        "version": VERSION,
        "algo": ALGO,
        "observation": "pixels",
        "uses_scripted_controller": False,
        "action_type": action_type,
        "classes": list(classes),
        "camera": cameras[0],  # the first camera, as files before "cameras" named it
        "cameras": cameras,
        "render_size": [int(render_size[0]), int(render_size[1])],
        "reads": [
            *PROPRIO_KEYS,
            *(f"{c}_rgb" for c in cameras),
            "object_class or target_class (optional)",
        ],
        "history": asdict(history),
        "features": "CNN(stacked frames) per camera + proprioception + class one-hot + "
        "previous actions + gripper-command history (scorbot_gym.policies.pixel); no pose "
        "estimate",
        "network": {
            "encoders": {
                "nature": "Nature-DQN conv 32x8x8/4, 64x4x4/2, 64x3x3/1, linear embedding",
                "spatial_softmax": "conv 32x5x5/2, 32x3x3/1, 32x3x3/1, 1x1 to K keypoint "
                "maps, spatial softmax to K (x, y), linear embedding",
            },
            "activation": "relu",
            "outputs": "5 arm (tanh) + 1 gripper logit (sign)",
        },
    }
