"""Hyperparameters of the training runs: YAML files shipped with the package, plus overrides.

As in RL Zoo, each algorithm has a file (``hyperparams/sac.yml``, ``tqc.yml``, ``ppo.yml``)
with one entry per setting (``default``: the policy acts alone; ``scratch``: the policy acts
alone and learns from scratch, with a normalised reward (SAC's ``normalized_pregrasp``);
``residual``: a correction on top of the scripted controller; ``finetune``, SAC only:
RLPD-style fine-tuning of a saved imitation policy, ``--init-policy``, see
:mod:`scorbot_gym.rl.finetune`). A run takes the entry its kind implies, or the one it names
(``--hyperparams-entry``), applies ``key=value`` overrides, checks every value, and records
the resolved set in its folder (``config.json`` and ``hyperparams.yml``), so a run is a
function of its folder, not of the package version.

``reward_type`` is the env's reward (an env setting kept with the hyperparameters, as RL Zoo
keeps ``env_kwargs``: the reward and the learner's settings are tuned together).
``reward_scale`` (default 1) multiplies the rewards the learner sees, SAC's "reward scale"
(Haarnoja et al. 2018): the env, its Monitor CSVs and the evaluations keep the env's reward.
The scratch entries use it because the normalised reward pays at most ``w`` a step (0.005
built for 0.99, 0.1 for 0.8: ``reward_gamma``): Q-values whose action dependence is ~1e-4
drown in the critic's initial output noise, so SAC did not climb the reward built for 0.99
where it climbed the same shaping at a 200-times larger scale.

``train_freq`` and ``gradient_steps`` (off-policy) are counted per env, as if there were one:
:func:`sb3_schedule` scales ``gradient_steps`` with the number of envs, so updates per env step
are the same whatever ``--n-envs`` is (SB3 counts ``train_freq`` in vector-env steps, each of
which is ``n_envs`` env steps). PPO's ``n_steps`` is the rollout over all envs.

This module imports only PyYAML: the CLI checks overrides while parsing arguments.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from importlib import resources
from pathlib import Path
from typing import Any

import yaml

ALGOS = ("sac", "tqc", "ppo")
#: the pose sources a run trains with ("occluded": the noisy oracle hidden by the hand)
POSES = ("oracle", "noisy", "occluded", "manifold")
SETTINGS = ("default", "scratch", "residual")  # every algorithm's file has these
FINETUNE = "finetune"  # the setting of --init-policy (sac.yml only)
OFF_POLICY = ("sac", "tqc")
#: the env's reward types (scorbot_gym.tasks.grasp.REWARD_TYPES; repeated here, as this module
#: imports PyYAML only, and a test checks that the two agree)
REWARD_TYPES = ("dense", "normalized_dense", "normalized_pregrasp", "sparse")
#: the discount the dense reward is built for (scorbot_gym.tasks.grasp.REWARD_GAMMA)
DENSE_REWARD_GAMMA = 0.99
#: what the policy is told of the object (scorbot_gym.policies.object_features.OBJECT_FEATURES)
OBJECT_FEATURES = ("class", "grasp_frame")


def _int(low: int) -> Callable[[Any], int]:
    def check(v: Any) -> int:
        if isinstance(v, bool) or not isinstance(v, int) or v < low:
            raise ValueError(f"must be an integer >= {low}")
        return v

    return check


def _float(low: float, high: float = math.inf, low_open: bool = False) -> Callable[[Any], float]:
    def check(v: Any) -> float:
        try:
            x = float(v) if not isinstance(v, bool) else math.nan
        except (TypeError, ValueError):
            x = math.nan
        if not (math.isfinite(x) and (x > low if low_open else x >= low) and x <= high):
            bracket = "(" if low_open else "["
            upper = "inf)" if high == math.inf else f"{high}]"
            raise ValueError(f"must be a number in {bracket}{low}, {upper}")
        return x

    return check


def _gradient_steps(v: Any) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or not (v >= 1 or v == -1):
        raise ValueError("must be an integer >= 1 (updates per train_freq env steps) or -1")
    return v


def _ent_coef_off_policy(v: Any) -> float | str:
    if isinstance(v, str) and (v == "auto" or v.startswith("auto_")):
        if v != "auto":
            _float(0.0, low_open=True)(v[5:])
        return v
    try:
        return _float(0.0)(v)
    except ValueError:
        raise ValueError("must be a number >= 0, 'auto' or 'auto_<initial value>'") from None


def _net_arch(v: Any) -> list[int]:
    if isinstance(v, int) and not isinstance(v, bool):
        v = [v]
    if (
        not isinstance(v, list)
        or not v
        or any(isinstance(n, bool) or not isinstance(n, int) or n < 1 for n in v)
    ):
        raise ValueError("must be a non-empty list of layer widths >= 1, e.g. [256, 256]")
    return list(v)


def _reward_type(v: Any) -> str:
    if v not in REWARD_TYPES:
        raise ValueError(f"must be one of {', '.join(REWARD_TYPES)}")
    return v


def _discount(v: Any) -> float:
    x = _float(0.0, 1.0, low_open=True)(v)
    if x == 1.0:
        raise ValueError("must be a number in (0, 1)")
    return x


def _object_features(v: Any) -> str:
    if v not in OBJECT_FEATURES:
        raise ValueError(f"must be one of {', '.join(OBJECT_FEATURES)}")
    return v


def _finite(v: Any) -> float:
    return _float(-math.inf)(v)


def _target_entropy(v: Any) -> float | str:
    if v == "auto":
        return v
    try:
        return _finite(v)
    except ValueError:
        raise ValueError("must be a number or 'auto' (minus the action dimension)") from None


#: key -> (algorithms it applies to, check-and-convert, what it is)
KEYS: dict[str, tuple[tuple[str, ...], Callable[[Any], Any], str]] = {
    "gamma": (ALGOS, _float(0.0, 1.0, low_open=True), "discount factor"),
    "learning_rate": (ALGOS, _float(0.0, low_open=True), "Adam step size"),
    "net_arch": (ALGOS, _net_arch, "hidden layer widths of actor and critic"),
    "log_std_init": (ALGOS, _finite, "initial log std of the actor (residual: exploration)"),
    "batch_size": (ALGOS, _int(1), "minibatch size"),
    "tau": (OFF_POLICY, _float(0.0, 1.0, low_open=True), "target network soft-update rate"),
    "buffer_size": (OFF_POLICY, _int(1), "replay buffer capacity (transitions)"),
    "learning_starts": (OFF_POLICY, _int(0), "env steps of random actions before updates"),
    "train_freq": (OFF_POLICY, _int(1), "env steps (per env) between update phases"),
    "gradient_steps": (OFF_POLICY, _gradient_steps, "updates per update phase (per env)"),
    "target_update_interval": (OFF_POLICY, _int(1), "updates between target updates"),
    "ent_coef": (ALGOS, _ent_coef_off_policy, "entropy coefficient (off-policy: 'auto_<init>')"),
    "n_quantiles": (("tqc",), _int(1), "quantiles per critic"),
    "top_quantiles_to_drop_per_net": (("tqc",), _int(0), "quantiles dropped per critic"),
    "n_critics": (OFF_POLICY, _int(1), "critic networks"),
    "n_steps": (("ppo",), _int(2), "rollout length over all envs"),
    "n_epochs": (("ppo",), _int(1), "passes over each rollout"),
    "gae_lambda": (("ppo",), _float(0.0, 1.0), "GAE lambda"),
    "clip_range": (("ppo",), _float(0.0, low_open=True), "PPO clip range"),
    "vf_coef": (("ppo",), _float(0.0), "value loss weight"),
    "max_grad_norm": (("ppo",), _float(0.0, low_open=True), "gradient clipping norm"),
    "target_entropy": (OFF_POLICY, _target_entropy, "entropy the auto ent_coef aims at"),
    # SAC with a starting policy worth keeping (fine-tuning, residual), see
    # scorbot_gym.rl.finetune.RLPDSAC
    "critic_warmup": (("sac",), _int(0), "first updates with actor and ent_coef frozen"),
    "actor_learning_rate": (("sac",), _float(0.0, low_open=True), "the actor's Adam step size"),
    # fine-tuning (--init-policy) only: the demonstrations
    "demo_ratio": (("sac",), _float(0.0, 1.0), "share of each batch drawn from demonstrations"),
    "bc_coef": (("sac",), _float(0.0), "BC term on demo samples, times mean |Q|"),
    # the env's reward, tuned with the rest (RL Zoo's env_kwargs)
    "reward_type": (ALGOS, _reward_type, "the env's reward (scorbot_gym.tasks.grasp)"),
    "reward_scale": (ALGOS, _float(0.0, low_open=True), "what the learner's rewards are times"),
    "reward_gamma": (ALGOS, _discount, "the discount a normalised reward is built for"),
    # the policy's inputs (an env wrapper, as RL Zoo's env_wrapper)
    "object_features": (ALGOS, _object_features, "the object's class one-hot, or its grasp frame"),
}

#: keys that only the fine-tuning setting reads (they weigh its demonstrations)
FINETUNE_KEYS = ("demo_ratio", "bc_coef")
#: keys that make an off-policy SAC run use :class:`scorbot_gym.rl.finetune.RLPDSAC`'s update
#: (a critic warm-up before the actor moves, and an actor step size of its own)
WARMUP_KEYS = ("critic_warmup", "actor_learning_rate")


#: checks that differ by algorithm: PPO's entropy coefficient is a fixed number
_ALGO_CHECKS: dict[tuple[str, str], Callable[[Any], Any]] = {("ppo", "ent_coef"): _float(0.0)}


def valid_keys(algo: str) -> list[str]:
    """The hyperparameters ``algo`` accepts, sorted."""
    return sorted(k for k, (algos, _, _) in KEYS.items() if algo in algos)


def setting_for(residual: bool, finetune: bool = False, entry: str | None = None) -> str:
    """The entry of the algorithm's file a run uses: ``entry`` if given, else the one its kind
    implies. The ``residual`` and ``finetune`` entries belong to those kinds of run, and those
    runs to them (their keys start the policy at the controller or the imitation policy);
    a policy acting alone may use any other entry (``default``, ``scratch``, ...)."""
    kind = FINETUNE if finetune else "residual" if residual else "default"
    if entry is None:
        return kind
    if not isinstance(entry, str) or not entry:
        raise ValueError(f"hyperparams entry must be a name such as 'scratch', got {entry!r}")
    if kind != "default" and entry != kind:
        run = "--init-policy" if finetune else "--residual"
        raise ValueError(f"a {run} run uses the hyperparams entry {kind!r}, got {entry!r}")
    if entry in (FINETUNE, "residual") and entry != kind:
        raise ValueError(
            f"the hyperparams entry {entry!r} is for {entry} runs; a policy acting alone uses "
            "'default', 'scratch' or another entry"
        )
    return entry


def load_defaults(algo: str, setting: str) -> dict[str, Any]:
    """The entry ``setting`` of the shipped ``hyperparams/<algo>.yml``, checked."""
    if algo not in ALGOS:
        raise ValueError(f"algo must be one of {ALGOS}, got {algo!r}")
    name = f"{algo}.yml"
    text = resources.files("scorbot_gym.rl").joinpath("hyperparams", name).read_text()
    entries = yaml.safe_load(text)
    if setting not in entries:
        raise ValueError(f"hyperparams/{name} has no entry {setting!r}; it has {sorted(entries)}")
    return check(algo, entries[setting], source=f"hyperparams/{name}[{setting}]", setting=setting)


def check(
    algo: str, values: dict[str, Any], source: str = "hyperparams", setting: str | None = None
) -> dict[str, Any]:
    """``values`` with each value checked and converted; one-line errors naming the key.
    With ``setting`` given, the fine-tuning keys are refused outside the fine-tuning setting."""
    if not isinstance(values, dict):
        raise ValueError(f"{source} must be a mapping of hyperparameter names to values")
    valid = valid_keys(algo)
    if setting is not None and setting != FINETUNE:
        valid = [k for k in valid if k not in FINETUNE_KEYS]
    out = {}
    for key, value in values.items():
        if key not in valid and key in FINETUNE_KEYS and algo in KEYS[key][0]:
            raise ValueError(f"{source}: {key} applies only to fine-tuning (--init-policy)")
        if key not in valid:
            raise ValueError(
                f"{source}: unknown hyperparameter {key!r} for {algo}; valid: {', '.join(valid)}"
            )
        try:
            out[key] = _ALGO_CHECKS.get((algo, key), KEYS[key][1])(value)
        except ValueError as exc:
            raise ValueError(f"{source}: {key} {exc}, got {value!r}") from None
    return out


def load_user_file(path: str | Path, algo: str, setting: str) -> dict[str, Any]:
    """The entry ``setting`` of a user's hyperparameter file (``--conf FILE.yml``: the schema
    of the shipped files, one mapping per setting; read with ``yaml.safe_load``), checked as
    the shipped entries are; one-line errors naming the file and what is wrong. Its values
    replace the shipped entry's (``--hyperparams`` overrides them in turn)."""
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise FileNotFoundError(f"--conf {path}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"--conf {path}: cannot read it ({exc})") from None
    try:
        entries = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or type(exc).__name__
        raise ValueError(f"--conf {path}: not valid YAML{where} ({problem})") from None
    if not isinstance(entries, dict) or not all(isinstance(k, str) for k in entries):
        raise ValueError(
            f"--conf {path} must map setting names ({', '.join((*SETTINGS, FINETUNE))}) to "
            "hyperparameters, as the package's hyperparams/<algo>.yml do"
        )
    if setting not in entries:
        raise ValueError(
            f"--conf {path} has no entry {setting!r} (the setting of this run); it has "
            f"{sorted(entries) or 'none'}"
        )
    return check(algo, entries[setting] or {}, source=f"{path}[{setting}]", setting=setting)


def parse_overrides(items: Iterable[str]) -> dict[str, Any]:
    """``["gamma=0.98", "net_arch=[256,256]"]`` -> values parsed as YAML (names not checked
    yet: that needs the algorithm, see :func:`resolve`)."""
    out: dict[str, Any] = {}
    for item in items:
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep or not key or not text.strip():
            raise ValueError(f"hyperparameter override {item!r} is not of the form key=value")
        if key in out:
            raise ValueError(f"hyperparameter {key!r} is given twice")
        try:
            out[key] = yaml.safe_load(text)
        except yaml.YAMLError:
            raise ValueError(f"hyperparameter {key}: cannot read the value {text!r}") from None
    return out


def resolve(
    algo: str,
    residual: bool,
    overrides: dict[str, Any],
    finetune: bool = False,
    entry: str | None = None,
) -> dict[str, Any]:
    """The shipped entry for (``algo``, setting) updated by the checked ``overrides``."""
    setting = setting_for(residual, finetune, entry)
    resolved = load_defaults(algo, setting)
    resolved.update(check(algo, overrides, setting=setting))
    check_reward_gamma(resolved)
    return dict(sorted(resolved.items()))


def check_reward_gamma(hp: dict[str, Any]) -> None:
    """``reward_gamma`` with what it applies to: a normalised reward (the others are built for
    one discount, 0.99), and a learner whose ``gamma`` is at most it (a larger discount values
    never finishing above a success under that reward; scorbot_gym.tasks.grasp)."""
    if "reward_gamma" not in hp:
        return
    reward, gamma, built_for = hp.get("reward_type", "dense"), hp.get("gamma"), hp["reward_gamma"]
    if not str(reward).startswith("normalized") and built_for != DENSE_REWARD_GAMMA:
        raise ValueError(
            f"hyperparams: reward_gamma applies to the normalised rewards; reward_type "
            f"{reward!r} is built for {DENSE_REWARD_GAMMA} (set reward_gamma={DENSE_REWARD_GAMMA})"
        )
    if gamma is not None and gamma > built_for:
        raise ValueError(
            f"hyperparams: gamma {gamma} is above reward_gamma {built_for}: under that reward "
            f"never finishing can be worth more than a success; set reward_gamma >= gamma"
        )


def sb3_schedule(algo: str, hp: dict[str, Any], n_envs: int) -> dict[str, Any]:
    """How the resolved set maps onto SB3's per-vector-step arguments for ``n_envs`` envs,
    and the resulting updates per env step (recorded in the run folder)."""
    if algo == "ppo":
        n_steps_per_env = max(8, hp["n_steps"] // n_envs)
        rollout = n_steps_per_env * n_envs
        batch = min(hp["batch_size"], rollout)
        minibatches = hp["n_epochs"] * math.ceil(rollout / batch)
        return {
            "n_steps_per_env": n_steps_per_env,
            "batch_size": batch,
            "updates_per_env_step": minibatches / rollout,
        }
    gs = hp["gradient_steps"]
    return {
        "train_freq": hp["train_freq"],
        "gradient_steps": gs * n_envs if gs > 0 else -1,
        "updates_per_env_step": gs / hp["train_freq"] if gs > 0 else 1.0,
    }


__all__ = [
    "ALGOS",
    "FINETUNE",
    "FINETUNE_KEYS",
    "KEYS",
    "WARMUP_KEYS",
    "POSES",
    "REWARD_TYPES",
    "SETTINGS",
    "check",
    "load_defaults",
    "load_user_file",
    "parse_overrides",
    "resolve",
    "sb3_schedule",
    "setting_for",
    "valid_keys",
]
