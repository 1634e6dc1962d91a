"""A trained stable-baselines3 model as a :class:`~scorbot_gym.policies.base.Policy`.

A saved policy is a directory (what ``scorbot-gym train`` exports and what ships in
``scorbot_gym/policies/data/``):

- ``model.safetensors``: the SB3 model's weights, with what rebuilds it (algorithm, policy,
  hyperparameters, spaces) as JSON in the header (:mod:`scorbot_gym.policies.sb3_files`): a
  format that cannot run code, unlike SB3's pickle-based ``model.zip``, which older versions
  wrote and which is refused (``scorbot-gym convert DIR --trust-pickle`` converts it);
- ``policy.json``: what the model needs around it: algorithm, action type, the classes of the
  ``object_class`` one-hot, the observation entries and shapes, the residual base controller's
  settings (if the policy is residual), and what it saw in training;
- ``normalize.npz`` (optional): the observation normalisation statistics (mean and variance
  per entry, as SB3's ``VecNormalize``), stored as plain arrays rather than a pickle.

The policy acts on the same observations as the scripted controller, so it runs through
:func:`scorbot_gym.evaluation.run_episode` and the comparison unchanged.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from scorbot_gym.policies.object_features import grasp_frame_observation, grasp_frame_space
from scorbot_gym.policies.scripted import ScriptedGraspPolicy

FORMAT = "scorbot-gym-policy"
VERSION = 1
#: the residual reading the grasp frame (``object_features: grasp_frame``), not the class
SHIPPED_GRASP_FRAME_RESIDUAL = Path(__file__).parent / "data" / "residual_sac_grasp_frame"
SHIPPED_POLICY = Path(__file__).parent / "data" / "residual_sac_oracle"
#: SAC from scratch (no controller, no demonstrations) reading the grasp frame
SHIPPED_SCRATCH_POLICY = Path(__file__).parent / "data" / "scratch_sac_grasp_frame"


def check_action_type(env, action_type: str) -> None:
    """A saved policy acts in one action space: a one-line error if ``env`` takes the other."""
    env_type = env.get_wrapper_attr("action_type")
    if env_type != action_type:
        raise ValueError(
            f"the policy outputs {action_type} actions, the env takes {env_type} actions "
            f"(use action_type={action_type!r})"
        )


def read_policy_json(meta_path: Path) -> dict[str, Any]:
    """``policy.json`` checked for format and version (one-line errors)."""
    try:
        meta = json.loads(Path(meta_path).read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{meta_path} is not valid JSON ({exc})") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise ValueError(f"{meta_path} is not a scorbot-gym policy description")
    if meta.get("version") != VERSION:
        raise ValueError(
            f"{meta_path} has format version {meta.get('version')}, this scorbot-gym reads "
            f"version {VERSION}"
        )
    if not isinstance(meta.get("algo"), str):
        raise ValueError(
            f"{meta_path}: algo must be a name (sac, tqc, ppo, imitation, pixel_imitation), "
            f"got {meta.get('algo')!r}"
        )
    return meta


def _algorithms() -> dict[str, Any]:
    from sb3_contrib import TQC
    from stable_baselines3 import PPO, SAC

    return {"sac": SAC, "tqc": TQC, "ppo": PPO}


class ObservationNormalizer:
    """``clip((x - mean) / sqrt(var + eps), -clip, clip)`` per observation entry (as
    ``VecNormalize``), from arrays; entries without statistics pass unchanged.

    Components that never varied in training (variance below ``CONSTANT_VAR``, e.g.
    ``pose_valid``, ``pose_confidence`` and ``pose_age`` under the oracle pose) are pinned to
    their training value, 0 after normalisation: the network never saw them change, so it
    cannot have learned what a change means, and ``VecNormalize`` would turn any deviation
    into the clip value (a 0 instead of 1 becomes -10). A policy trained with the oracle then
    reads an estimator's held, low-confidence estimate the way the scripted controller does:
    as the object's pose.
    """

    #: variance under which a component counts as constant in training (std 1e-3)
    CONSTANT_VAR = 1e-6

    def __init__(
        self, mean: dict[str, np.ndarray], var: dict[str, np.ndarray], clip: float, eps: float
    ) -> None:
        self.mean, self.var, self.clip, self.eps = mean, var, float(clip), float(eps)
        self.source = "normalize.npz"  # the file, where loaded from one (for error messages)

    @property
    def constant(self) -> dict[str, np.ndarray]:
        """Per entry, which components were constant in training (pinned at inference)."""
        return {k: np.asarray(v) < self.CONSTANT_VAR for k, v in self.var.items()}

    def __call__(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        out = dict(obs)
        for k, m in self.mean.items():
            x = (np.asarray(obs[k], np.float64) - m) / np.sqrt(self.var[k] + self.eps)
            x = np.where(np.asarray(self.var[k]) < self.CONSTANT_VAR, 0.0, x)
            out[k] = np.clip(x, -self.clip, self.clip).astype(np.float32)
        return out

    def check_shapes(self, shapes: dict[str, tuple[int, ...]]) -> None:
        """Every entry's statistics must be finite arrays of that entry's shape in ``shapes``
        (a damaged ``normalize.npz`` would fail at the first action, deep inside numpy)."""
        for what, stats in (("mean", self.mean), ("var", self.var)):
            for key, value in stats.items():
                v = np.asarray(value)
                if key not in shapes or v.shape != tuple(shapes[key]) or v.dtype.kind not in "fiu":
                    raise ValueError(
                        f"{self.source}: {what}/{key} must be numbers of shape "
                        f"{shapes.get(key, 'an observation entry of policy.json')}, got "
                        f"{v.dtype} {v.shape}"
                    )
                if not np.isfinite(v).all() or (what == "var" and (v < 0).any()):
                    need = "finite and >= 0" if what == "var" else "finite"
                    raise ValueError(f"{self.source}: {what}/{key} must be {need} numbers")
        if set(self.mean) != set(self.var):
            raise ValueError(f"{self.source}: mean/ and var/ must name the same entries")

    @classmethod
    def from_vec_normalize(cls, venv) -> ObservationNormalizer:
        keys = venv.norm_obs_keys or list(venv.obs_rms)
        return cls(
            {k: np.array(venv.obs_rms[k].mean) for k in keys},
            {k: np.array(venv.obs_rms[k].var) for k in keys},
            venv.clip_obs,
            venv.epsilon,
        )

    def save(self, path: Path) -> None:
        arrays = {f"mean/{k}": v for k, v in self.mean.items()}
        arrays.update({f"var/{k}": v for k, v in self.var.items()})
        np.savez(path, clip=self.clip, eps=self.eps, **arrays)

    @classmethod
    def load(cls, path: Path) -> ObservationNormalizer:
        with np.load(path, allow_pickle=False) as z:
            mean = {k[5:]: z[k] for k in z.files if k.startswith("mean/")}
            var = {k[4:]: z[k] for k in z.files if k.startswith("var/")}
            normalizer = cls(mean, var, float(z["clip"]), float(z["eps"]))
        normalizer.source = str(path)
        return normalizer


def residual_action(base: np.ndarray, residual: np.ndarray, scale: float) -> np.ndarray:
    """A residual policy's action: the base action plus the scaled residual, in [-1, 1]. A
    residual shorter than the base (the arm's components only) leaves the rest to the base."""
    out = np.array(base, np.float64)
    residual = np.asarray(residual, np.float64)
    out[..., : residual.shape[-1]] += scale * residual
    return np.clip(out, -1.0, 1.0).astype(np.float32)


class SB3Policy:
    """Deterministic actions of an SB3 model, on raw observations from ``make_env``.

    ``meta`` is the content of ``policy.json``. For a residual policy the scripted base runs
    here too (built from ``meta["residual"]["base"]``), so the caller's env is the plain one.
    """

    def __init__(
        self,
        model: Any,
        meta: dict[str, Any],
        normalizer: ObservationNormalizer | None = None,
    ) -> None:
        self.model, self.meta, self.normalizer = model, meta, normalizer
        res = meta.get("residual")
        self.residual_scale = float(res["scale"]) if res else None
        self.base = ScriptedGraspPolicy(**res["base"]) if res else None
        self.classes = tuple(meta.get("classes") or ())
        self._env_classes: tuple[str, ...] | None = None
        #: "grasp_frame": the model reads :func:`grasp_frame_observation`'s view (no class)
        self.object_features = (
            (meta.get("config") or {}).get("hyperparams", {}).get("object_features", "class")
        )

    # --- loading ---------------------------------------------------------------------------
    @classmethod
    def load(cls, path: str | Path) -> SB3Policy:
        """A policy directory (or its ``model.safetensors``); one-line errors for bad files.
        Loading runs no code from the folder (see :mod:`scorbot_gym.policies.sb3_files`)."""
        from scorbot_gym.policies.sb3_files import (
            MODEL_FILE,
            OLD_MODEL_FILE,
            load_model,
            old_format_message,
        )

        path = Path(path)
        if path.is_file() and path.name in (MODEL_FILE, OLD_MODEL_FILE):
            path = path.parent
        if not path.is_dir():
            raise FileNotFoundError(
                f"no policy directory at {path} (expected {MODEL_FILE} and "
                "policy.json from `scorbot-gym train`)"
            )
        meta_path, model_path = path / "policy.json", path / MODEL_FILE
        if not model_path.is_file() and (path / OLD_MODEL_FILE).is_file():
            raise ValueError(old_format_message(path))
        for p in (meta_path, model_path):
            if not p.is_file():
                raise FileNotFoundError(f"policy {path} is missing {p.name}")
        meta = read_policy_json(meta_path)
        algos = _algorithms()
        if not isinstance(meta.get("algo"), str) or meta["algo"] not in algos:
            raise ValueError(
                f"{meta_path}: algo must be one of {sorted(algos)}, got {meta.get('algo')!r}"
            )
        model = load_model(model_path)
        if not isinstance(model, algos[meta["algo"]]):
            raise ValueError(
                f"{model_path} holds a {type(model).__name__} model, policy.json says "
                f"{meta['algo']!r}"
            )
        norm_path = path / "normalize.npz"
        normalizer = None
        if norm_path.is_file():
            try:
                normalizer = ObservationNormalizer.load(norm_path)
            except Exception as exc:  # zip/npy/key errors of a damaged file
                raise ValueError(f"{norm_path} is damaged ({type(exc).__name__}: {exc})") from None
        elif meta.get("normalize", (meta.get("config") or {}).get("normalize")):
            raise FileNotFoundError(
                f"policy {path} is missing normalize.npz (policy.json says the model was "
                "trained on normalised observations)"
            )
        policy = cls(model, meta, normalizer)
        policy._check_model()
        return policy

    def _check_model(self) -> None:
        """The model's observation space must be the one ``policy.json`` describes, and the
        normalisation statistics must have its entries' shapes."""
        space = self.model.observation_space
        want = {k: tuple(v) for k, v in self.meta["observation_shapes"].items()}
        have = {k: tuple(s.shape) for k, s in getattr(space, "spaces", {}).items()}
        if have != want:
            raise ValueError(
                f"incompatible policy: the model observes {have}, policy.json says {want}"
            )
        if self.normalizer is not None:
            self.normalizer.check_shapes(want)

    def bind(self, env) -> SB3Policy:
        """Check that ``env`` gives the observations the model was trained on and remember the
        env's class names, so that an ``object_class`` one-hot over other classes (``--object
        box`` makes a one-class env; a user-added object is a class the model never saw) is
        re-ordered into the model's. Returns ``self``."""
        check_action_type(env, self.meta["action_type"])
        space = env.observation_space
        if self.object_features == "grasp_frame":
            space = grasp_frame_space(space)
        have = {k: tuple(s.shape) for k, s in space.spaces.items()}
        if self.base is not None:
            have["base_action"] = tuple(env.action_space.shape)
        want = {k: tuple(v) for k, v in self.meta["observation_shapes"].items()}
        self._env_classes = None
        if self.object_features == "grasp_frame":  # the frame's mesh: named by the env's one-hot
            self._env_classes = tuple(env.get_wrapper_attr("class_names"))
            if self.base is not None:
                self.base.classes = self._env_classes
        elif "object_class" in want and "object_class" in have:
            names = tuple(env.get_wrapper_attr("class_names"))
            self._env_classes = names if names != self.classes else None
            have["object_class"] = want["object_class"]
            if self.base is not None:
                self.base.classes = names  # the base reads the env's one-hot as it is
        if have != want:
            diff = sorted(set(have.items()) ^ set(want.items()))
            raise ValueError(f"wrong observation space for this policy: entries that differ {diff}")
        return self

    def _model_onehot(self, onehot: np.ndarray) -> np.ndarray:
        """The env's one-hot in the model's class order; an object the model has no class
        for (a user-added one) shows as no class at all."""
        out = np.zeros(len(self.classes))
        for name, v in zip(self._env_classes, onehot, strict=True):
            if name in self.classes:
                out[self.classes.index(name)] = v
        return out

    def env_kwargs(self) -> dict[str, Any]:
        """Keywords for :func:`scorbot_gym.make_env` that give this policy its observations."""
        cartesian = self.meta["action_type"] == "cartesian"
        env_id = "ScorbotGraspCartesian-v0" if cartesian else "ScorbotGrasp-v0"
        if self.object_features == "grasp_frame":  # any object the env has: its own one-hot
            return {"env_id": env_id, "classes": None}
        return {"env_id": env_id, "classes": list(self.classes) or None}

    # --- Policy protocol -------------------------------------------------------------------
    def reset(self, obs: dict[str, np.ndarray], info: dict[str, Any] | None = None) -> None:
        if self.base is not None:
            self.base.reset(obs, info)

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        base = None
        if self.base is not None:
            base = np.asarray(self.base.act(obs), np.float32)
            obs = {**obs, "base_action": base}
        if self.object_features == "grasp_frame":
            obs = grasp_frame_observation(obs, self._env_classes or self.classes)
        elif self._env_classes is not None:
            obs = {**obs, "object_class": self._model_onehot(obs["object_class"])}
        x = {k: np.asarray(obs[k]) for k in self.meta["observation_shapes"]}
        if self.normalizer is not None:
            x = self.normalizer(x)
        action, _ = self.model.predict(x, deterministic=True)
        action = np.clip(np.asarray(action, np.float64), -1.0, 1.0)
        if base is not None:
            return residual_action(base, action, self.residual_scale)
        return np.clip(action, -1.0, 1.0).astype(np.float32)

    @property
    def replans(self) -> int:
        return self.base.replans if self.base is not None else 0
