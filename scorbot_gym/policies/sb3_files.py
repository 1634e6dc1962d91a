"""SB3 algorithms in files that cannot run code: every tensor in safetensors, the rest JSON.

SB3's own ``model.zip`` keeps the spaces, the policy class and the schedules as cloudpickle (the
``":serialized:"`` entries of its ``data``) and its weights as torch pickles, so loading a zip
someone handed you runs whatever it holds. Policies and checkpoints are shared ("try my policy
folder"), so they are written here as one ``model.safetensors`` file instead:

- the tensors: the policy's ``state_dict``; for a training checkpoint also each optimiser's state
  and the entropy coefficient (SB3's ``_get_torch_save_params``);
- in the header's metadata, one JSON description: the algorithm class and policy alias (looked up
  in a fixed table, never imported by name), the constructor's plain hyperparameters, the
  observation and action spaces (``Box`` / ``Dict`` with their bounds), the structure of the
  optimisers' state dicts (their tensors named by key), and for a checkpoint the counters a
  resumed run continues from.

Reading parses a JSON header and raw arrays, nothing else; keys that would name a class or a
function (``*_class``, ``*_fn``) are refused, so a crafted file can describe only plain numbers,
strings and lists. The algorithm is rebuilt the way SB3's ``load`` rebuilds it (constructor
without an env, spaces set, ``_setup_model``), then the tensors are loaded into it.
"""

from __future__ import annotations

import inspect
import json
import math
from collections import deque
from enum import Enum
from pathlib import Path
from typing import Any

import numpy as np

FORMAT = "scorbot-gym-sb3"
VERSION = 1
MODEL_FILE = "model.safetensors"
#: SB3's pickle-based archive, written by scorbot-gym before this format
OLD_MODEL_FILE = "model.zip"
_METADATA_KEY = "scorbot_gym"
#: constructor arguments not recorded: objects, or what the loader decides (device, logging)
_NOT_RECORDED = frozenset(
    {
        "self",
        "policy",
        "env",
        "device",
        "verbose",
        "tensorboard_log",
        "_init_setup_model",
        "policy_kwargs",
        "action_noise",
        "replay_buffer_class",
        "replay_buffer_kwargs",
        "rollout_buffer_class",
        "rollout_buffer_kwargs",
        "supported_action_spaces",
        "support_multi_env",
        "monitor_wrapper",
    }
)
_BOX_DTYPES = frozenset(
    {"float16", "float32", "float64", "int8", "int16", "int32", "int64", "uint8", "uint16"}
)


def old_format_message(path: Path, what: str = "policy") -> str:
    """The one-line refusal of a folder written in SB3's pickle-based format."""
    return (
        f"{path} holds a {what} in the old pickle-based format (model.zip, *.pkl), which can run "
        f"code when loaded; if you trust where it came from, convert it once with "
        f"`scorbot-gym convert {path} --trust-pickle`"
    )


def algorithm_classes() -> dict[str, type]:
    """The algorithm classes a file may name (by class name)."""
    from sb3_contrib import TQC
    from stable_baselines3 import PPO, SAC

    from scorbot_gym.rl.finetune import RLPDSAC

    return {"SAC": SAC, "TQC": TQC, "PPO": PPO, "RLPDSAC": RLPDSAC}


# --- spaces ----------------------------------------------------------------------------------
def _bound_to_json(values: np.ndarray) -> Any:
    """Box bounds: one number if all are equal, else a flat list; infinities as strings."""
    flat = [v if math.isfinite(v) else str(v) for v in np.asarray(values, np.float64).ravel()]
    return flat[0] if flat and all(v == flat[0] for v in flat) else flat


def _bound_from_json(value: Any, shape: tuple[int, ...], dtype: np.dtype) -> np.ndarray:
    items = value if isinstance(value, list) else [value] * int(np.prod(shape, dtype=np.int64))
    for v in items:
        if isinstance(v, bool) or not isinstance(v, (int, float, str)):
            raise ValueError(f"a Box bound must be a number, got {v!r}")
    return np.array([float(v) for v in items], np.float64).reshape(shape).astype(dtype)


def space_to_json(space) -> dict[str, Any]:
    """A ``Box`` or ``Dict`` of them as JSON (what a rebuilt model's space is made from)."""
    from gymnasium import spaces

    if isinstance(space, spaces.Dict):
        return {"type": "Dict", "spaces": {k: space_to_json(s) for k, s in space.spaces.items()}}
    if isinstance(space, spaces.Box):
        return {
            "type": "Box",
            "shape": list(space.shape),
            "dtype": space.dtype.name,
            "low": _bound_to_json(space.low),
            "high": _bound_to_json(space.high),
        }
    raise ValueError(f"a {type(space).__name__} space cannot be saved (Box and Dict only)")


def space_from_json(data: Any):
    from gymnasium import spaces

    kind = data.get("type") if isinstance(data, dict) else None
    if kind == "Dict" and isinstance(data.get("spaces"), dict):
        return spaces.Dict({str(k): space_from_json(v) for k, v in data["spaces"].items()})
    if kind == "Box":
        shape = data.get("shape")
        if not (isinstance(shape, list) and all(isinstance(n, int) and n >= 0 for n in shape)):
            raise ValueError(f"a Box shape must be a list of sizes, got {shape!r}")
        if data.get("dtype") not in _BOX_DTYPES:
            raise ValueError(f"a Box dtype must be one of {sorted(_BOX_DTYPES)}")
        dtype = np.dtype(data["dtype"])
        low = _bound_from_json(data.get("low"), tuple(shape), dtype)
        high = _bound_from_json(data.get("high"), tuple(shape), dtype)
        return spaces.Box(low, high, tuple(shape), dtype)
    raise ValueError(f"unknown space description {str(data)[:80]!r} (Box and Dict only)")


# --- nested state (optimiser state dicts) as JSON + named tensors ------------------------------
def _plain(value: Any) -> Any:
    """``value`` as JSON (enums by value, tuples as lists, numpy scalars as numbers), or raise
    TypeError for anything else (classes, functions, schedules, objects)."""
    if isinstance(value, Enum):
        value = value.value
    if isinstance(value, np.generic):
        value = value.item()
    if value is None or isinstance(value, (bool, int, str)):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else {"float": str(value)}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, dict) and all(isinstance(k, str) for k in value):
        return {k: _plain(v) for k, v in value.items()}
    raise TypeError(f"{type(value).__name__} is not a plain value")


def _encode(obj: Any, tensors: dict[str, Any], key: str) -> Any:
    """A state dict as JSON: tensors stored under ``key`` paths, containers tagged by kind (int
    keys and tuples survive the round trip, as optimiser state dicts need)."""
    import torch as th

    if isinstance(obj, th.Tensor):
        tensors[key] = obj.detach().cpu().clone().contiguous()
        return {"tensor": key}
    if isinstance(obj, dict):
        if not all(isinstance(k, (str, int)) and not isinstance(k, bool) for k in obj):
            raise TypeError(f"state keys must be strings or integers, got {list(obj)[:5]}")
        return {"dict": [[k, _encode(v, tensors, f"{key}/{k}")] for k, v in obj.items()]}
    if isinstance(obj, (list, tuple)):
        kind = "tuple" if isinstance(obj, tuple) else "list"
        return {kind: [_encode(v, tensors, f"{key}/{i}") for i, v in enumerate(obj)]}
    return _plain(obj)


def _decode(node: Any, tensors: dict[str, Any]) -> Any:
    if node is None or isinstance(node, (bool, int, float, str)):
        return node
    if not (isinstance(node, dict) and len(node) == 1):
        raise ValueError(f"unexpected state entry {str(node)[:80]!r}")
    ((kind, value),) = node.items()
    if kind == "tensor" and isinstance(value, str):
        if value not in tensors:
            raise ValueError(f"the tensor {value!r} is missing")
        return tensors[value]
    if kind == "float" and value in ("inf", "-inf", "nan"):
        return float(value)
    if kind == "dict" and isinstance(value, list):
        out = {}
        for item in value:
            if not (isinstance(item, list) and len(item) == 2 and isinstance(item[0], (str, int))):
                raise ValueError(f"unexpected dict entry {str(item)[:80]!r}")
            out[item[0]] = _decode(item[1], tensors)
        return out
    if kind in ("list", "tuple") and isinstance(value, list):
        items = [_decode(v, tensors) for v in value]
        return tuple(items) if kind == "tuple" else items
    raise ValueError(f"unexpected state entry {str(node)[:80]!r}")


def _from_json(value: Any) -> Any:
    """A recorded hyperparameter back (non-finite floats were tagged)."""
    if isinstance(value, dict):
        if set(value) == {"float"} and value["float"] in ("inf", "-inf", "nan"):
            return float(value["float"])
        return {k: _from_json(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_from_json(v) for v in value]
    return value


# --- describing and writing a model ----------------------------------------------------------
def _constructor_names(cls: type) -> set[str]:
    names: set[str] = set()
    for klass in cls.__mro__:
        init = vars(klass).get("__init__")
        if init is None:
            continue
        for p in inspect.signature(init).parameters.values():
            if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY):
                names.add(p.name)
    return names - _NOT_RECORDED


def _policy_alias(model) -> str:
    for alias, klass in model.policy_aliases.items():
        if klass is type(model.policy):
            return alias
    raise ValueError(
        f"{type(model.policy).__name__} is not one of {type(model).__name__}'s policies"
    )


def describe(model) -> dict[str, Any]:
    """What rebuilds ``model`` (before its tensors are loaded): class, policy alias, the plain
    constructor hyperparameters (schedules and objects are left to their defaults: they do not
    change a policy's actions), policy keywords and spaces."""
    hyperparams = {}
    for name in sorted(_constructor_names(type(model))):
        if hasattr(model, name):
            try:
                hyperparams[name] = _plain(getattr(model, name))
            except TypeError:
                pass  # a schedule or an object: not needed to act, not recordable as data
    try:
        policy_kwargs = _plain(dict(model.policy_kwargs))
    except TypeError as exc:
        raise ValueError(f"the policy keywords cannot be saved without pickle ({exc})") from None
    return {
        "format": FORMAT,
        "version": VERSION,
        "class": type(model).__name__,
        "policy": _policy_alias(model),
        "hyperparams": hyperparams,
        "policy_kwargs": policy_kwargs,
        "observation_space": space_to_json(model.observation_space),
        "action_space": space_to_json(model.action_space),
    }


def save_model(model, path: str | Path, training: bool = False) -> None:
    """Write ``model`` to ``path`` (a ``.safetensors`` file): the policy's weights, or with
    ``training`` everything a resumed run needs (optimisers, entropy coefficient, counters)."""
    from safetensors.torch import save
    from stable_baselines3.common.save_util import recursive_getattr

    description = describe(model)
    states, variables = (["policy"], []) if not training else model._get_torch_save_params()
    tensors: dict[str, Any] = {}
    description["states"] = {
        name: _encode(recursive_getattr(model, name).state_dict(), tensors, name) for name in states
    }
    description["variables"] = {}
    for name in variables:
        value = recursive_getattr(model, name)
        if value is not None:
            description["variables"][name] = _encode(value, tensors, f"variables/{name}")
    if training:
        description["progress"] = {
            "num_timesteps": int(model.num_timesteps),
            "n_updates": int(model._n_updates),
            "episode_num": int(model._episode_num),
            "ep_info_buffer": _plain(list(model.ep_info_buffer or [])),
            "ep_success_buffer": _plain(list(model.ep_success_buffer or [])),
        }
    # written by Python (safetensors' own file writer makes it readable by its owner only)
    Path(path).write_bytes(save(tensors, metadata={_METADATA_KEY: json.dumps(description)}))


# --- reading ---------------------------------------------------------------------------------
def read_model_file(path: str | Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """The description and the tensors of a file :func:`save_model` wrote (one-line errors)."""
    from safetensors import safe_open

    path = Path(path)
    try:
        with safe_open(str(path), framework="pt", device="cpu") as f:
            metadata = f.metadata() or {}
            tensors = {k: f.get_tensor(k) for k in f.keys()}
    except Exception as exc:  # safetensors raises its own error kinds on a damaged header
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise ValueError(f"{path} is not a safetensors model file ({msg})") from None
    try:
        description = json.loads(metadata.get(_METADATA_KEY, ""))
    except json.JSONDecodeError:
        raise ValueError(f"{path} has no scorbot-gym model description") from None
    if not isinstance(description, dict) or description.get("format") != FORMAT:
        raise ValueError(f"{path} is not a scorbot-gym model file")
    if description.get("version") != VERSION:
        raise ValueError(
            f"{path} has format version {description.get('version')!r}, this scorbot-gym reads "
            f"version {VERSION}"
        )
    return description, tensors


def _checked_keywords(values: Any, where: str) -> dict[str, Any]:
    if not isinstance(values, dict):
        raise ValueError(f"{where} must be an object")
    for key in values:
        if key.endswith(("_class", "_fn")) or key in _NOT_RECORDED:
            raise ValueError(f"{where} may not set {key!r} (a file cannot name code)")
    return {k: _from_json(v) for k, v in values.items()}


def _build(description: dict[str, Any]):
    """The algorithm of ``description``, set up as SB3's ``load`` sets it up (no env)."""
    classes = algorithm_classes()
    cls = classes.get(description.get("class"))
    if cls is None:
        raise ValueError(f"class {description.get('class')!r} is not one of {sorted(classes)}")
    if description.get("policy") not in cls.policy_aliases:
        raise ValueError(
            f"policy {description.get('policy')!r} is not one of {sorted(cls.policy_aliases)}"
        )
    hyperparams = _checked_keywords(description.get("hyperparams"), "hyperparams")
    unknown = set(hyperparams) - _constructor_names(cls)
    if unknown:
        raise ValueError(f"unknown hyperparameters for {cls.__name__}: {sorted(unknown)}")
    if isinstance(hyperparams.get("train_freq"), list):
        hyperparams["train_freq"] = tuple(hyperparams["train_freq"])
    model = cls(
        policy=description["policy"],
        env=None,
        device="cpu",
        policy_kwargs=_checked_keywords(description.get("policy_kwargs"), "policy_kwargs"),
        _init_setup_model=False,
        **hyperparams,
    )
    model.observation_space = space_from_json(description.get("observation_space"))
    model.action_space = space_from_json(description.get("action_space"))
    model.n_envs = 1
    model._setup_model()
    return model


def load_model(path: str | Path):
    """The algorithm in ``path`` with its policy's weights, for acting (``model.predict``)."""
    description, tensors = read_model_file(path)
    try:
        model = _build(description)
        state = _decode((description.get("states") or {}).get("policy"), tensors)
        model.policy.load_state_dict(state, strict=True)
    except Exception as exc:  # SB3 / torch raise many kinds on a description that does not fit
        msg = str(exc).splitlines()[0] if str(exc) else ""
        raise ValueError(
            f"{path} could not be loaded as a {description.get('class')} model "
            f"({type(exc).__name__}: {msg[:300]})"
        ) from None
    return model


def restore_training_state(model, path: str | Path) -> None:
    """Load a checkpoint :func:`save_model` wrote with ``training=True`` into ``model`` (built
    from the run's configuration): weights, optimisers, entropy coefficient, counters.

    Everything lands on ``model.device`` whatever device wrote the file (the file's tensors are
    read onto the CPU): the weights and the variables (``log_ent_coef``, ``ent_coef_tensor``)
    are copied into the model's own tensors, which keeps their device, dtype and identity (the
    entropy optimiser holds ``log_ent_coef`` itself), and ``Optimizer.load_state_dict`` moves
    each optimiser state onto its parameter's device. SB3's own ``load`` assigns ``.data``,
    which is safe there only because it reads the variables onto the model's device first;
    assigning a CPU tensor's ``.data`` to a CUDA model's ``log_ent_coef`` moves it to the CPU,
    and the first update then mixes devices.
    """
    import torch as th

    description, tensors = read_model_file(path)
    mine = describe(model)
    for key in ("class", "policy", "observation_space", "action_space"):
        if description.get(key) != mine[key]:
            raise ValueError(f"{path} is for another model: its {key} differs from the run's")
    progress = description.get("progress")
    if not isinstance(progress, dict):
        raise ValueError(f"{path} holds a policy, not a training checkpoint")
    states, variables = model._get_torch_save_params()
    stored = description.get("states") or {}
    if set(stored) != set(states):
        raise ValueError(f"{path} holds the states {sorted(stored)}, the model has {states}")
    try:
        params = {name: _decode(stored[name], tensors) for name in states}
        model.set_parameters(params, exact_match=True, device=model.device)
        stored_vars = description.get("variables") or {}
        for name in variables:
            target = getattr(model, name, None)
            if name in stored_vars and target is not None:
                value = _decode(stored_vars[name], tensors)
                if not isinstance(value, th.Tensor) or value.shape != target.shape:
                    raise ValueError(f"{name} must be a tensor of shape {tuple(target.shape)}")
                with th.no_grad():
                    target.copy_(value)
        model.num_timesteps = int(progress["num_timesteps"])
        model._n_updates = int(progress["n_updates"])
        model._episode_num = int(progress["episode_num"])
        window = model._stats_window_size
        model.ep_info_buffer = deque(list(progress["ep_info_buffer"]), maxlen=window)
        model.ep_success_buffer = deque(list(progress["ep_success_buffer"]), maxlen=window)
    except Exception as exc:  # torch raises many kinds on state dicts that do not fit
        msg = str(exc).splitlines()[0] if str(exc) else ""
        raise ValueError(
            f"{path} does not fit the run's model ({type(exc).__name__}: {msg[:300]})"
        ) from None


__all__ = [
    "FORMAT",
    "MODEL_FILE",
    "OLD_MODEL_FILE",
    "VERSION",
    "describe",
    "load_model",
    "old_format_message",
    "read_model_file",
    "restore_training_state",
    "save_model",
    "space_from_json",
    "space_to_json",
]
