"""Scripted vs learned grasping, paired: the table (and figure) a paper would print.

Every arm (a policy under a pose condition) runs the same episode seeds ``seed ... seed+N-1``,
so the object, its placement and the pose-noise draws are the same across arms and the arms
can be compared episode by episode. Per arm: how the policy was trained, success rate with a
95 % Wilson interval, the paired difference to the scripted controller (Newcombe's 95 %
interval for *paired* proportions, method 10, Newcombe 1998, Stat. Med. 17:2635, and McNemar's
exact test on the discordant episodes), steps to success, failure causes, per-object success.
Per policy: success against pose-noise level.

**Policies** (arms) are names from :data:`BUILTIN_ARMS` (``scripted``, ``random``, ``rl``: the
shipped residual, ``learned``: the shipped stand-alone imitation policy, ``finetuned``: that
policy after RLPD-style fine-tuning; a new built-in is one
entry there) or any policy folder (with ``policy.json``, loaded by
:func:`scorbot_gym.policies.loading.load_policy`), or a ``scorbot-gym train`` run folder (its
final ``policy/``; not ``best/``, which was chosen on evaluation episodes that may share these
seeds).

**Pose conditions**: ``oracle``; ``noisy@S`` (``noisy_oracle`` with x-y position noise S
metres and heading noise ``S * DEG_PER_M`` degrees, i.e. 1 cm goes with 5 degrees);
``noisy@S:Y`` (position S metres, heading Y degrees, e.g. ``noisy@0.02:20``); ``occluded``
(``occluded_oracle`` with its defaults: the noisy oracle, 5 mm and 5 degrees, lost while the
hand is within 6-20 cm of the object, so the policy acts from a held estimate as it does with
an image estimator; not a noise level); ``occluded@D`` or ``occluded@LOW:HIGH`` (the same,
hidden within D metres, or within a distance drawn per episode from LOW-HIGH); ``manifold`` (the
pose-manifold estimator from a ``scorbot-gym pose train`` model file, or without one the default
models of the top camera, trained on first use and cached, as ``scorbot-gym rollout`` uses) with
**no privileged input**, as the main arm of ``benchmarks/closed_loop.py``: masks from background
subtraction (:data:`MANIFOLD_SEGMENTER`) and the object's identity recognised
(:data:`MANIFOLD_RECOGNIZER`, fused over :data:`MANIFOLD_CAMERAS`), never given; ``chance``
(the rotation-blind chance level beside it, the project's rule for every estimator figure:
the position still comes from the image, only the rotation ignores it):
exactly ``manifold`` with the default models - same cameras, masks and recognition (the default
models recognise; the pose estimates their appearance check makes are dropped) - but the
estimator swapped for :class:`pose.baselines.ChanceEstimator` (one constant rotation, the
training views' medoid, placed at the silhouette), fitted on the views the default models are
trained on (:func:`scorbot_gym.perception.baseline_models.baseline_models`, cached beside
them). It is always beside the *default* models: ``pose_model`` changes ``manifold`` only.

**The report** (what :func:`compare` returns and ``--json`` writes):

- ``seeds`` ``[first, last]``, ``episodes`` (per arm), ``objects`` (``null``: the catalogue),
  ``action_type``, ``cartesian_ik`` (the env's IK for Cartesian actions: ``closed_form``, or
  ``dls`` for damped least squares every step; a report without it is from before
  2026-11-28, when every run used ``dls``), ``estimate_every``, ``reference`` (the policy
  differences are taken
  against: ``scripted`` when it is an arm, else the first), ``difference_method``,
  ``noise_heading_deg_per_m``, ``wall_s`` (of the whole comparison);
- ``conditions``: ``[{label, source, noise_pos_m, noise_yaw_deg, identity, segmenter,
  estimator}]`` in run order (``identity``: ``given`` to the pose source, or ``recognize``d by
  it; ``segmenter``: where the estimator's masks come from, ``null`` for the oracle sources;
  ``estimator``: what answers the pose from the image, ``manifold`` (the trained models) or
  ``chance`` (rotation-blind: the image's position, a constant rotation), ``null`` for the
  oracle sources);
- ``arms``: ``{policy: {label, training}}`` where ``training`` is :func:`training_record`:
  ``trained_from`` (``scripted``: the hand-written controller itself; ``residual``: a learned
  correction on top of it; ``demonstrations``: imitation of scripted demonstrations, perhaps
  fine-tuned by RL; ``none``: RL from scratch; ``untrained``: random actions),
  ``uses_scripted_controller`` (at test time), ``algo``, ``demonstration_episodes``,
  ``env_steps``, ``wall_time_s``, ``seeds`` and ``source`` (the folder) - ``null`` wherever
  the policy folder does not record it (never guessed);
- ``results``: one record per arm: ``policy``, ``label``, ``pose``, ``pose_source``,
  ``noise_pos_m``, ``noise_yaw_deg`` (``null`` for the estimator), ``episodes``,
  ``successes``, ``success_rate``, ``ci95``, ``steps_to_success`` ``{median, q25, q75, mean}``
  (successful episodes only; ``null`` without any), ``median_steps_to_success``,
  ``mean_steps_to_success``, ``failure_causes`` (count per cause), ``per_object``
  (``{object: {episodes, successes, success_rate, ci95}}``), ``perception`` (the pose source's
  record, ``null`` for none), ``training`` (as in ``arms``), ``saw_scripted_controller`` (as
  the policy folder records it, ``null`` for none), ``vs_reference`` (``null`` for the
  reference, else as a ``differences`` entry) and ``episode_success`` (a string of ``0``/``1``,
  one per seed in order: enough to redo any paired statistic);
- ``differences``: per pose condition and non-reference policy ``{pose, a, b, diff, ci95,
  only_a, only_b, mcnemar_p}`` (``a - b``, ``b`` the reference);
- ``noise_curves``: ``{policy: [{pose, noise_pos_m, noise_yaw_deg, episodes, success_rate,
  ci95}]}`` over the oracle (noise 0) and every ``noisy`` condition, by increasing noise (the
  estimator conditions, ``manifold`` and ``chance``, are no noise level: not on the curves).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from scorbot_gym.envs.factory import make_env
from scorbot_gym.envs.grasp import CARTESIAN_IKS
from scorbot_gym.evaluation.chunks import parallel, run_chunked
from scorbot_gym.evaluation.episodes import EpisodeResult, run_episodes
from scorbot_gym.evaluation.summary import newcombe_paired_diff, summarize, wilson_interval
from scorbot_gym.perception.calibration import DEFAULT_CALIBRATION
from scorbot_gym.perception.recognizers import DEFAULT_RECOGNIZER
from scorbot_gym.perception.support import DEFAULT_SUPPORT
from scorbot_gym.policies import RandomPolicy, ScriptedGraspPolicy
from scorbot_gym.policies.loading import SHIPPED
from scorbot_gym.rl import runs

DEG_PER_M = 500.0  # heading noise (deg) per metre of position noise in noisy@S conditions
REFERENCE = "scripted"
#: the ``manifold`` condition: no privileged input (the main arm of benchmarks/closed_loop.py)
MANIFOLD_SEGMENTER = "background"  # masks by background subtraction, not the renderer's
MANIFOLD_RECOGNIZER = DEFAULT_RECOGNIZER  # identity recognised, not given (before 2026-11-27:
# "flr+appearance", which compare.json's estimator conditions record)
MANIFOLD_CAMERAS = ("top", "side")  # pose from the first; recognition fused over both
#: the pose-condition names (besides one ``noisy@S[:Y]`` per noise level, and ``occluded@...``)
POSE_CONDITIONS = ("oracle", "noisy", "occluded", "manifold", "chance")
#: the pose estimators of the estimator conditions (``manifold``: the trained models)
ESTIMATOR_CONDITIONS = ("manifold", "chance")


# ---- pose conditions ----------------------------------------------------------------------


@dataclass(frozen=True)
class PoseCondition:
    label: str
    source: str
    kwargs: dict[str, Any]
    noise_m: float | None  # position noise (0 for the oracle; None when not a noise level)
    noise_yaw_deg: float | None = None  # heading noise (0 for the oracle)
    identity: str = "given"  # or "recognize": the pose source is not told the object
    estimator: str | None = None  # what answers the pose from the image (None: an oracle)

    def record(self) -> dict[str, Any]:
        """The condition as the report's ``conditions`` lists it."""
        return {
            "label": self.label,
            "source": self.source,
            "noise_pos_m": self.noise_m,
            "noise_yaw_deg": self.noise_yaw_deg,
            "identity": self.identity,
            "segmenter": self.kwargs.get("segmenter"),
            "estimator": self.estimator,
        }


def hide_range(text: str) -> tuple[float, float]:
    """``"D"`` or ``"LOW:HIGH"`` (metres) -> the ``occluded@`` condition's hide distances;
    one-line error for anything else."""
    parts = text.split(":")
    try:
        if len(parts) > 2:
            raise ValueError
        low = float(parts[0])
        high = float(parts[-1])
        if not (np.isfinite(low) and np.isfinite(high) and 0 <= low <= high):
            raise ValueError
    except ValueError:
        raise ValueError(
            f"occluded@{text}: expected occluded@D or occluded@LOW:HIGH, hide distances in "
            "metres with 0 <= LOW <= HIGH, e.g. occluded@0.1 or occluded@0.06:0.2"
        ) from None
    return low, high


def noise_level(level: float | str | tuple[float, float]) -> tuple[float, float]:
    """``S`` (metres; heading ``S * DEG_PER_M`` degrees), ``"S:Y"`` or ``(S, Y)`` (Y degrees)
    -> ``(position_m, heading_deg)``; one-line error for anything else."""
    if isinstance(level, str):
        parts = level.split(":")
        try:
            if len(parts) > 2:
                raise ValueError
            pos = float(parts[0])
            yaw = float(parts[1]) if len(parts) == 2 else pos * DEG_PER_M
        except ValueError:
            raise ValueError(
                f"noise level {level!r}: expected S (position std in metres) or S:Y "
                "(and heading std in degrees), e.g. 0.01 or 0.02:20"
            ) from None
    elif isinstance(level, tuple | list):
        pos, yaw = (float(v) for v in level)
    else:
        pos = float(level)
        yaw = pos * DEG_PER_M
    if not (np.isfinite(pos) and pos >= 0 and np.isfinite(yaw) and yaw >= 0):
        raise ValueError(
            f"noise levels are position std (m) and heading std (deg) >= 0, got {pos}, {yaw}"
        )
    return pos, yaw


def noise_label(pos: float, yaw: float) -> str:
    """``noisy@S`` when the heading noise is the default for S, else ``noisy@S:Y``."""
    default = np.isclose(yaw, pos * DEG_PER_M)
    return f"noisy@{pos:g}" if default else f"noisy@{pos:g}:{yaw:g}"


def pose_conditions(
    poses: Sequence[str],
    noise: Sequence[float | str | tuple[float, float]] = (),
    pose_model: str | Path | None = None,
) -> list[PoseCondition]:
    """:data:`POSE_CONDITIONS` names, plus one ``noisy@S[:Y]`` per noise level.

    ``manifold`` without ``pose_model``, and ``chance`` always, get their models (the defaults,
    and the chance set fitted on their views) from :func:`with_models`, which :func:`compare`
    calls once for every arm."""
    out: list[PoseCondition] = []
    for p in poses:
        if p == "oracle":
            out.append(PoseCondition("oracle", "oracle", {}, 0.0, 0.0))
        elif p == "occluded":  # the source's defaults (what scratch_occluded trains on)
            out.append(PoseCondition("occluded", "occluded_oracle", {}, None))
        elif p.startswith("occluded@"):  # one hide distance range, to calibrate against
            low, high = hide_range(p[len("occluded@") :])
            kw = {"hide_distance_m": [low, high]}
            out.append(PoseCondition(f"occluded@{low:g}:{high:g}", "occluded_oracle", kw, None))
        elif p in ESTIMATOR_CONDITIONS:  # the same source; chance swaps the estimator only
            kw: dict[str, Any] = {
                "segmenter": MANIFOLD_SEGMENTER,
                "recognizer": MANIFOLD_RECOGNIZER,
                "cameras": list(MANIFOLD_CAMERAS),
                "support": DEFAULT_SUPPORT,  # recorded (compare.json before 2026-11-27: "table")
                "calibration": DEFAULT_CALIBRATION,  # recorded (compare.json before: "none")
            }
            if p == "manifold" and pose_model is not None:
                kw["models"] = str(pose_model)
            out.append(PoseCondition(p, "manifold", kw, None, identity="recognize", estimator=p))
        elif p == "noisy":
            noise = list(noise) or [0.01]
        else:
            valid = ", ".join(POSE_CONDITIONS)
            raise ValueError(f"unknown pose condition {p!r}; valid: {valid}, occluded@D[:HIGH]")
    for level in noise:
        pos, yaw = noise_level(level)
        kw = {"pos_sigma_m": pos, "yaw_sigma_deg": yaw}
        out.append(PoseCondition(noise_label(pos, yaw), "noisy_oracle", kw, pos, yaw))
    labels = [c.label for c in out]
    if not out:
        raise ValueError("give at least one pose condition")
    if len(set(labels)) != len(labels):
        raise ValueError(f"a pose condition is given twice: {', '.join(labels)}")
    return out


# ---- arms: a policy and how it was trained ------------------------------------------------


@dataclass
class Arm:
    """One policy of the comparison: how to build it on an env, and how it was trained."""

    name: str  # as given: a built-in name or a folder
    label: str  # short, for tables and figures
    build: Callable[[Any, int], Any]  # (env, seed) -> Policy
    training: dict[str, Any]
    env_kwargs: dict[str, Any] = field(default_factory=dict)  # what the policy needs of make_env
    meta: dict[str, Any] = field(default_factory=dict)  # policy.json of a saved policy


def _training(
    trained_from: str, uses_controller: bool, source: str | None = None, **known: Any
) -> dict[str, Any]:
    keys = ("algo", "demonstration_episodes", "env_steps", "wall_time_s", "seeds")
    return {
        "trained_from": trained_from,
        "uses_scripted_controller": uses_controller,
        **{k: known.get(k) for k in keys},
        "source": source,
    }


def _scripted_arm(name: str) -> Arm:
    return Arm(
        name,
        name,
        lambda env, seed: ScriptedGraspPolicy.for_env(env),
        _training("scripted", True),
    )


def _random_arm(name: str) -> Arm:
    return Arm(
        name,
        name,
        lambda env, seed: RandomPolicy(env.action_space, seed),
        _training("untrained", False),
    )


def _shipped(folder: Path) -> Callable[[str], Arm]:
    return lambda name: saved_arm(folder, name=name)


#: built-in policy names -> arm factory; a new shipped policy is one entry of ``SHIPPED``
BUILTIN_ARMS: dict[str, Callable[[str], Arm]] = {
    "scripted": _scripted_arm,
    "random": _random_arm,
    **{name: _shipped(folder) for name, folder in SHIPPED.items()},
}


def _read_json(path: Path) -> dict[str, Any] | None:
    """A JSON object from a run's bookkeeping, or ``None`` if absent or unreadable (then the
    figure it would have given is reported as unknown, never guessed)."""
    try:
        return runs.read_json(path)
    except (OSError, ValueError):
        return None


def policy_folder(path: str | Path) -> Path:
    """A saved policy folder (``policy.json`` inside), a file in one, or a training run folder
    (its final ``policy/``, via :func:`scorbot_gym.rl.runs.policy_dir`); one-line error
    listing the valid names for anything else."""
    path = Path(path)
    if not path.exists():
        raise ValueError(
            f"unknown policy {str(path)!r}; valid: {', '.join(BUILTIN_ARMS)}, or a policy "
            "folder (with policy.json) or a `scorbot-gym train` run folder"
        )
    return runs.policy_dir(path.parent if path.is_file() else path, checkpoint="last")


def _source(folder: Path) -> str:
    """The folder as a reader can find it: package-relative for a shipped policy (not this
    machine's install path), as given otherwise."""
    package = Path(__file__).resolve().parent.parent
    try:
        return str(Path(package.name) / Path(folder).resolve().relative_to(package))
    except ValueError:
        return str(folder)


def training_record(folder: Path, meta: dict[str, Any]) -> dict[str, Any]:
    """How a saved policy was trained, from its ``policy.json`` (``uses_scripted_controller``,
    ``residual``, ``saw_scripted_controller``, ``training``, ``trained_timesteps``, ``config``)
    and, for a run's ``policy/`` folder, the run's ``checkpoint/state.json`` (env steps and
    training wall time at the export) and ``config.json``. Unrecorded figures are ``None``."""
    train = meta.get("training") if isinstance(meta.get("training"), dict) else {}
    saw = meta.get("saw_scripted_controller")
    saw = saw if isinstance(saw, dict) else {}
    uses = meta.get("uses_scripted_controller")
    if uses is None:
        uses = meta.get("residual") is not None or bool(saw.get("residual_base"))
    demos = train.get("demonstration_episodes", saw.get("bc_demo_episodes"))
    if uses:
        trained_from = "residual"
    elif demos or meta.get("algo") == "imitation":
        trained_from = "demonstrations"
    else:
        trained_from = "none"
    config = meta.get("config") or train.get("config") or {}
    env_steps = train.get("env_steps", meta.get("trained_timesteps"))
    wall = train.get("wall_time_s", train.get("wall_s"))
    seed = config.get("seed") if isinstance(config, dict) else None
    # a run folder's final export: the run's own bookkeeping (a fine-tune's policy.json already
    # sums both stages, which the run's state, RL steps only, would undercount)
    if folder.name == runs.POLICY and "rl_finetune" not in train:
        state = _read_json(folder.parent / runs.CHECKPOINT / runs.STATE) or {}
        env_steps = state.get("timesteps", env_steps)
        wall = state.get("wall_s", wall)
        seed = (_read_json(folder.parent / runs.CONFIG) or {}).get("seed", seed)
    return _training(
        trained_from,
        bool(uses),
        _source(folder),
        algo=meta.get("algo"),
        demonstration_episodes=demos,
        env_steps=None if env_steps is None else int(env_steps),
        wall_time_s=None if wall is None else float(wall),
        seeds=None if seed is None else [int(seed)],
    )


def load_policy(folder: str | Path) -> Any:
    """The saved policy in ``folder`` (a policy folder; see :func:`policy_folder`), whatever
    kind its ``policy.json`` says it is (SB3, imitation)."""
    from scorbot_gym.policies.loading import load_policy as load_saved

    return load_saved(folder, checkpoint="last")


def saved_arm(path: str | Path, name: str | None = None) -> Arm:
    """An arm from a policy folder or a run folder."""
    folder = policy_folder(path)
    policy = load_policy(folder)
    name = str(path) if name is None else name
    return Arm(
        name,
        policy_label(name),
        lambda env, seed: policy.bind(env),
        training_record(folder, policy.meta),
        policy.env_kwargs(),
        policy.meta,
    )


def resolve_arm(name: str) -> Arm:
    """A built-in name (:data:`BUILTIN_ARMS`) or a policy / run folder; one-line error listing
    the valid names otherwise."""
    if name in BUILTIN_ARMS:
        return BUILTIN_ARMS[name](name)
    return saved_arm(name)


def policy_label(policy: str) -> str:
    """``scripted``, ``rl``, or a policy directory's run name (``runs/bc/policy`` -> ``bc``,
    ``runs/bc/best`` -> ``bc/best``)."""
    p = Path(policy)
    if p.name == runs.POLICY:
        return p.parent.name
    return f"{p.parent.name}/{p.name}" if p.name == runs.BEST else p.name


# ---- running and recording ----------------------------------------------------------------


def _run_arm(
    name: str,
    cond: PoseCondition,
    episodes: int,
    seed: int,
    objects: list[str] | None,
    action_type: str,
    estimate_every: int,
    cartesian_ik: str,
    progress: bool,
    threads: int | None = None,
) -> list[EpisodeResult]:
    """The episodes of one arm (a worker process's job under ``jobs > 1``)."""
    if threads is not None:
        import torch

        torch.set_num_threads(threads)  # one-sample predictions: threads only add contention
    arm = resolve_arm(name)
    kw = dict(arm.env_kwargs)
    env_id = kw.pop("env_id", None) or (
        "ScorbotGraspCartesian-v0" if action_type == "cartesian" else "ScorbotGrasp-v0"
    )
    env = make_env(
        env_id,
        pose=cond.source,
        pose_kwargs=cond.kwargs,
        estimate_every=estimate_every,
        identity=cond.identity,
        objects=objects,
        cartesian_ik=cartesian_ik,
        **kw,
    )
    try:
        return run_episodes(env, arm.build(env, seed), episodes, seed, progress=progress)
    finally:
        env.close()


def _quartiles(values: list[int]) -> dict[str, float] | None:
    if not values:
        return None
    q25, med, q75 = np.percentile(values, [25, 50, 75])
    mean = float(np.mean(values))
    return {"median": float(med), "q25": float(q25), "q75": float(q75), "mean": mean}


def _record(arm: Arm, cond: PoseCondition, results: list[EpisodeResult]) -> dict:
    s = summarize(results)
    steps = _quartiles([r.steps for r in results if r.success])
    per_object = {}
    for obj, v in sorted(s["per_object"].items()):
        per_object[obj] = {
            **v,
            "success_rate": v["successes"] / v["episodes"],
            "ci95": list(wilson_interval(v["successes"], v["episodes"])),
        }
    return {
        "policy": arm.name,
        "label": arm.label,
        "pose": cond.label,
        "pose_source": cond.source,
        "noise_pos_m": cond.noise_m,
        "noise_yaw_deg": cond.noise_yaw_deg,
        "episodes": s["episodes"],
        "successes": s["successes"],
        "success_rate": s["success_rate"],
        "ci95": s["success_rate_ci95"],
        "steps_to_success": steps,
        "median_steps_to_success": steps["median"] if steps else None,
        "mean_steps_to_success": s["mean_steps_to_success"],
        "failure_causes": s["failure_causes"],
        "per_object": per_object,
        "perception": s["perception"],
        "training": arm.training,
        "saw_scripted_controller": arm.meta.get("saw_scripted_controller"),
        "vs_reference": None,
        "episode_success": "".join("1" if r.success else "0" for r in results),
    }


def _successes(record: dict) -> list[bool]:
    return [c == "1" for c in record["episode_success"]]


def noise_curves(results: list[dict]) -> dict[str, list[dict[str, Any]]]:
    """Per policy: success over the oracle (noise 0) and the ``noisy`` conditions, by
    increasing (position, heading) noise."""
    curves: dict[str, list[dict[str, Any]]] = {}
    for r in results:
        if r["noise_pos_m"] is None:
            continue
        curves.setdefault(r["policy"], []).append(
            {k: r[k] for k in ("pose", "noise_pos_m", "noise_yaw_deg", "episodes")}
            | {"success_rate": r["success_rate"], "ci95": r["ci95"]}
        )
    for points in curves.values():
        points.sort(key=lambda p: (p["noise_pos_m"], p["noise_yaw_deg"]))
    return curves


def with_models(
    conds: Sequence[PoseCondition], progress: bool = True, jobs: int = 1
) -> list[PoseCondition]:
    """The conditions with the models their pose source runs, trained or fitted (or read from
    the cache) here, once, not in every worker: a ``manifold`` condition without a model file
    gets the default models (:func:`~scorbot_gym.perception.training.default_pose_models`);
    ``chance`` gets the ``chance`` set fitted on the same objects and views
    (:func:`~scorbot_gym.perception.baseline_models.baseline_models`, ``jobs`` objects at a
    time) and the default models' recognition without the pose estimates it makes
    (:class:`~scorbot_gym.perception.recognizers.IdentityOnlyRecognizer`): only the estimator
    differs."""
    if not any(c.source == "manifold" and "models" not in c.kwargs for c in conds):
        return list(conds)
    from scorbot_gym.perception.references import default_models
    from scorbot_gym.perception.training import IN_LOOP_TRAINING

    models = default_models(progress=progress, training=IN_LOOP_TRAINING)
    out = []
    for c in conds:
        if c.source != "manifold" or "models" in c.kwargs:
            out.append(c)
        elif c.estimator == "chance":
            out.append(replace(c, kwargs={**c.kwargs, **_chance_kwargs(c, models, progress, jobs)}))
        else:
            out.append(replace(c, kwargs={**c.kwargs, "models": models}))
    return out


def _chance_kwargs(cond: PoseCondition, models: Any, progress: bool, jobs: int) -> dict:
    """The ``chance`` condition's models and recogniser
    (:func:`~scorbot_gym.perception.baseline_models.baseline_source_kwargs`: fitted on
    ``models``'s objects and training views, ``models``'s recognition without its estimates)."""
    from scorbot_gym.perception.baseline_models import baseline_source_kwargs

    kw = cond.kwargs
    return baseline_source_kwargs("chance", models, kw["recognizer"], kw["cameras"], jobs, progress)


def _map(jobs: int, tasks: list[tuple], ray: str | None = None) -> list[list[EpisodeResult]]:
    """Run :func:`_run_arm` over ``tasks``, under ``jobs > 1`` in spawned processes (as Ray
    tasks with ``ray``), each task cut into chunks of its seeds
    (:func:`~scorbot_gym.evaluation.chunks.run_chunked`; one thread, no progress bar in a
    worker); every episode depends only on its seed, so the results do not depend on
    ``jobs`` or the runner."""
    workers = parallel(jobs, ray)

    def chunk_args(i: int, n: int, first: int) -> tuple:
        t = tasks[i]  # a worker: no progress bar, one thread
        return (*t[:2], n, first, *t[4:-1], False, 1) if workers else (*t[:2], n, first, *t[4:])

    done = run_chunked(_run_arm, [(t[2], t[3]) for t in tasks], chunk_args, jobs, ray)
    return [[r for chunk in chunks for r in chunk] for chunks in done]


def compare(
    policies: list[str],
    poses: list[str],
    episodes: int,
    seed: int = 0,
    noise: Sequence[float | str | tuple[float, float]] = (),
    pose_model: str | Path | None = None,
    objects: list[str] | None = None,
    action_type: str = "cartesian",
    estimate_every: int = 1,
    progress: bool = True,
    jobs: int = 1,
    ray: str | None = None,
    cartesian_ik: str = "closed_form",
) -> dict[str, Any]:
    """Run every policy under every pose condition on the same seeds; returns the report
    described in the module docstring (``jobs`` processes, each running a chunk of an arm, or
    Ray tasks with ``ray``: ``"local"`` or a cluster address; the results do not depend on
    either)."""
    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}")
    if jobs < 1:
        raise ValueError(f"jobs must be >= 1, got {jobs}")
    if not policies:
        raise ValueError(f"give at least one policy ({', '.join(BUILTIN_ARMS)} or a policy folder)")
    if len(set(policies)) != len(policies):
        raise ValueError(f"a policy is given twice: {', '.join(policies)}")
    if cartesian_ik not in CARTESIAN_IKS:
        raise ValueError(f"cartesian_ik must be one of {CARTESIAN_IKS}, got {cartesian_ik!r}")
    conds = pose_conditions(poses, noise, pose_model)
    arms = {p: resolve_arm(p) for p in policies}  # bad names fail here, before any episode
    conds = with_models(conds, progress=progress, jobs=jobs)  # once, for every arm
    reference = REFERENCE if REFERENCE in policies else policies[0]
    start = time.perf_counter()
    tasks = [
        (p, c, episodes, seed, objects, action_type, estimate_every, cartesian_ik, progress)
        for c in conds
        for p in policies
    ]
    episodes_run = _map(jobs, tasks, ray)
    results = [_record(arms[t[0]], t[1], eps) for t, eps in zip(tasks, episodes_run, strict=True)]
    diffs = []
    for cond in conds:
        by = {r["policy"]: r for r in results if r["pose"] == cond.label}
        ref = by[reference]
        for name in policies:
            if name == reference:
                continue
            d = newcombe_paired_diff(_successes(by[name]), _successes(ref))
            diff = {"pose": cond.label, "a": name, "b": reference, **d}
            by[name]["vs_reference"] = diff
            diffs.append(diff)
    return {
        "seeds": [seed, seed + episodes - 1],
        "episodes": episodes,
        "objects": objects,
        "action_type": action_type,
        "cartesian_ik": cartesian_ik,
        "estimate_every": estimate_every,
        "reference": reference,
        "difference_method": "Newcombe (1998) method 10 paired-proportion interval; McNemar "
        "exact test",
        "noise_heading_deg_per_m": DEG_PER_M,
        "wall_s": time.perf_counter() - start,
        "conditions": [c.record() for c in conds],
        "arms": {p: {"label": a.label, "training": a.training} for p, a in arms.items()},
        "results": results,
        "differences": diffs,
        "noise_curves": noise_curves(results),
    }


# ---- the figure ---------------------------------------------------------------------------

TRAINED_FROM = {
    "scripted": "scripted controller",
    "residual": "controller + learned correction",
    "demonstrations": "learned from demonstrations, no controller",
    "none": "RL from scratch, no controller",
    "untrained": "random actions",
}


def _pct_ci(rate: float, ci: Sequence[float]) -> str:
    return f"{100 * rate:.1f} % ({100 * ci[0]:.1f}–{100 * ci[1]:.1f})"


def _diff_text(d: dict[str, Any]) -> str:
    lo, hi = d["ci95"]
    p = d["mcnemar_p"]
    return f"Δ {100 * d['diff']:+.1f} ({100 * lo:+.1f} to {100 * hi:+.1f}), p = {p:.2g}"


def headline(report: dict[str, Any], pose: str | None = None) -> str:
    """The headline numbers under the first (or the given) pose condition, one line per
    policy: success with its interval and, for the others, the paired difference to the
    reference with McNemar's p; then, where the report has the ``chance`` condition, the
    chance level beside them (each policy's success with the rotation-blind pose: image
    position, constant rotation)."""
    pose = pose or report["results"][0]["pose"]
    seeds = report["seeds"]
    lines = [f"{pose}, {report['episodes']} paired episodes (seeds {seeds[0]}–{seeds[-1]})"]
    for r in report["results"]:
        if r["pose"] != pose:
            continue
        text = f"{r['label']}: {_pct_ci(r['success_rate'], r['ci95'])}"
        if r.get("vs_reference"):
            text += f"; {_diff_text(r['vs_reference'])} vs {r['vs_reference']['b']}"
        lines.append(text)
    chance = [r for r in report["results"] if r["pose"] == "chance"]
    if chance and pose != "chance":
        levels = ", ".join(f"{r['label']} {_pct_ci(r['success_rate'], r['ci95'])}" for r in chance)
        lines.append(f"chance level (rotation-blind: image position, constant rotation): {levels}")
    return "\n".join(lines)


def plot_comparison(report: dict[str, Any], path: str | Path) -> list[str]:
    """The comparison figure (:func:`scorbot_gym.evaluation.compare_plot.plot_comparison`:
    success per arm, the paired differences as a forest plot, per object, pose noise)."""
    from scorbot_gym.evaluation.compare_plot import plot_comparison as plot

    return plot(report, path)


# ---- the table ----------------------------------------------------------------------------


def _md_pct_ci(rate: float, ci: Sequence[float]) -> str:
    lo, hi = (100 * v for v in ci)
    return f"{100 * rate:.1f} % ({lo:.1f}–{hi:.1f})"


def _md_training(t: dict[str, Any]) -> str:
    """What the policy folder records of its training; "—" where it records nothing."""
    if t["trained_from"] in ("scripted", "untrained"):
        return "—"
    parts = []
    if t.get("algo"):
        parts.append(str(t["algo"]))
    if t.get("demonstration_episodes"):
        parts.append(f"{t['demonstration_episodes']} demos")
    steps = t.get("env_steps")
    parts.append("env steps not recorded" if steps is None else f"{steps:,} env steps")
    wall = t.get("wall_time_s")
    parts.append("wall time not recorded" if wall is None else f"{wall:,.0f} s wall")
    if t.get("seeds"):
        parts.append("seed " + ", ".join(map(str, t["seeds"])))
    return ", ".join(parts)


def markdown_table(report: dict[str, Any]) -> str:
    """The comparison as one markdown table, one row per arm: policy, how it was trained (and
    the training cost its folder records, "not recorded" where it records none), pose
    condition, success with its 95 % interval, the paired difference to the reference with its
    interval and McNemar's p, steps to success as median [quartiles], failure causes."""
    ref = report.get("reference", report["results"][0]["policy"])
    head = [
        "policy",
        "trained from",
        "training",
        "pose",
        "success (95 % CI)",
        f"Δ vs {ref} (95 % CI)",
        "McNemar p",
        "steps to success",
        "failures",
    ]
    rows = []
    for r in report["results"]:
        t = r["training"]
        d = r.get("vs_reference")
        diff, p = "—", "—"
        if d:
            lo, hi = (100 * v for v in d["ci95"])
            diff = f"{100 * d['diff']:+.1f} pts ({lo:+.1f} to {hi:+.1f})"
            p = f"{d['mcnemar_p']:.2g}"
        s = r.get("steps_to_success")
        steps = "—" if not s else f"{s['median']:.0f} [{s['q25']:.0f}–{s['q75']:.0f}]"
        fails = ", ".join(f"{n} {c}" for c, n in r["failure_causes"].items() if n) or "none"
        rows.append(
            [
                f"`{r['label']}`",
                TRAINED_FROM.get(t["trained_from"], t["trained_from"]),
                _md_training(t),
                f"`{r['pose']}`",
                _md_pct_ci(r["success_rate"], r["ci95"]),
                diff,
                p,
                steps,
                fails,
            ]
        )
    lines = ["| " + " | ".join(head) + " |", "| " + " | ".join("---" for _ in head) + " |"]
    return "\n".join(lines + ["| " + " | ".join(row) + " |" for row in rows]) + "\n"
