"""Scripted demonstrations as Minari datasets (Farama's standard for offline RL data).

A dataset holds, per episode: the wrapped env's observations (proprioception and the pose
estimator's outputs: ``object_pos``/``object_quat``, ``pose_valid``, ``pose_confidence``,
``pose_age``, ``object_class``), the executed actions (the controller's plus DART noise, if
any), rewards, terminations, truncations, and flat numeric infos with the same keys at every
step (outcome, true pose and class, reward terms, the estimator's record, each camera's
calibration ``camera_<name>_K`` / ``_world_from_camera`` / ``_size``) plus ``expert_action``:
the scripted controller's clean action on that observation, given the oracle pose, which is
the label :func:`scorbot_gym.rl.imitation.train_imitation` learns from.

The dataset records the env it was recorded on (Minari's ``env_spec``, with the pose wrapper:
``minari.load_dataset(NAME).recover_environment()`` rebuilds it; a pose source made from a
loaded model set is rebuilt with its default models, whose identity the settings record) and,
in its metadata under :data:`SETTINGS_KEY`, the action type, pose source and pose-model hash,
seeds, DART sigma, command and code version. :func:`read_dataset` returns the episodes with
these settings, and the imitation trainer refuses a dataset of another action type than its
env's.

Datasets live under ``MINARI_DATASETS_PATH`` (Minari's default: ``~/.minari/datasets``). The id
is checked (well formed, not taken, the folder writable) before any episode runs, and a dataset
appears whole or not at all: it is written under a hidden staging folder and renamed into place,
so a killed run leaves nothing that Minari lists or that blocks a rerun.

    from scorbot_gym.rl.datasets import record_demonstrations, read_dataset
    record_demonstrations("scorbot/grasp-oracle-v0", episodes=100, pose="oracle")
    demos = read_dataset("scorbot/grasp-oracle-v0")   # or minari.load_dataset(...)
    demos.settings["action_type"], len(demos.episodes)
"""

from __future__ import annotations

import contextlib
import json
import os
import sys
import warnings
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from scorbot_gym import seeds as seed_ranges
from scorbot_gym.names import IDENTITIES
from scorbot_gym.outputs import (
    check_dataset_id,
    datasets_root,
    exclusive_lock,
    parse_dataset_id,
    staging_dir,
)
from scorbot_gym.rl.imitation import DemonstrationSet, LabelledEpisode, collect_episodes

LABEL_KEY = "expert_action"
POSES = ("oracle", "manifold")
#: the dataset metadata key holding how the demonstrations were recorded
SETTINGS_KEY = "scorbot_gym_settings"


def to_episode_buffer(episode: LabelledEpisode, index: int):
    """One :class:`LabelledEpisode` as Minari's ``EpisodeBuffer`` (labels in the infos)."""
    from minari.data_collector import EpisodeBuffer

    return EpisodeBuffer(
        id=index,
        seed=episode.seed,
        observations={k: np.asarray(v) for k, v in episode.observations.items()},
        actions=np.asarray(episode.actions, np.float32),
        rewards=list(map(float, episode.rewards)),
        terminations=list(map(bool, episode.terminations)),
        truncations=list(map(bool, episode.truncations)),
        infos={**episode.infos, LABEL_KEY: np.asarray(episode.labels, np.float32)},
    )


@contextlib.contextmanager
def _minari_root(path: os.PathLike) -> Iterator[None]:
    """Minari's dataset folder pointed at ``path`` for the body (Minari reads
    ``MINARI_DATASETS_PATH`` at every call)."""
    before = os.environ.get("MINARI_DATASETS_PATH")
    os.environ["MINARI_DATASETS_PATH"] = os.fspath(path)
    try:
        yield
    finally:
        if before is None:
            del os.environ["MINARI_DATASETS_PATH"]
        else:
            os.environ["MINARI_DATASETS_PATH"] = before


@contextlib.contextmanager
def reserve_dataset_id(dataset_id: str) -> Iterator[None]:
    """Check ``dataset_id`` (well formed, not taken, writable; one-line errors) and hold it for
    the body: a second process recording the same id is refused at once, not after its
    episodes."""
    check_dataset_id(dataset_id, "dataset")
    locks = datasets_root() / ".scorbot-gym-locks"
    locks.mkdir(parents=True, exist_ok=True)
    with exclusive_lock(locks / f"{dataset_id.replace('/', '__')}.lock", f"dataset {dataset_id!r}"):
        yield


def _move_namespace_records(staging: Path, root: Path, namespace: str | None) -> None:
    """The namespace folders Minari made in ``staging`` (each with its metadata file), made in
    ``root`` where they are missing; existing namespaces keep their own metadata."""
    parts = namespace.split("/") if namespace else []
    for depth in range(1, len(parts) + 1):
        level = Path(*parts[:depth])
        (root / level).mkdir(exist_ok=True)
        for record in (staging / level).glob("*.json"):
            if not (root / level / record.name).exists():
                os.replace(record, root / level / record.name)


def _recordable_env(env):
    """``env`` when its spec can be written as JSON (what Minari stores as ``env_spec``),
    else ``None`` with a warning (the dataset then cannot rebuild its env)."""
    spec = getattr(env, "spec", None)
    try:
        spec.to_json()
    except Exception as exc:  # noqa: BLE001 - gymnasium raises several kinds for odd kwargs
        warnings.warn(f"the env's spec is not recordable ({exc}); no env_spec", stacklevel=3)
        return None
    return env


def write_dataset(
    dataset_id: str,
    episodes: Sequence[LabelledEpisode],
    env,
    *,
    description: str,
    algorithm_name: str = "ScriptedGraspPolicy (oracle-pose labels) + DART noise",
    settings: dict[str, Any] | None = None,
):
    """Create the Minari dataset ``dataset_id`` from episodes; returns the ``MinariDataset``.

    Minari writes it into a hidden staging folder beside the datasets, which is then renamed
    into place in one step: the dataset is whole or absent, never half-written. The env's spec
    is stored as Minari's ``env_spec`` and ``settings`` (default: the env's action type, the
    episodes' seeds) under :data:`SETTINGS_KEY` in the metadata."""
    import minari

    from scorbot_gym.rl.provenance import code_version

    target = check_dataset_id(dataset_id, "dataset")
    recorded = {
        "action_type": env.get_wrapper_attr("action_type"),
        "episodes": len(episodes),
        "seeds": [int(ep.seed) for ep in episodes],
        "command": list(sys.argv),
        "code": code_version(),
        **(settings or {}),
    }
    json.dumps(recorded)  # a setting that is not JSON fails here, before the dataset is made
    buffers = [to_episode_buffer(ep, i) for i, ep in enumerate(episodes)]
    root = datasets_root()
    with staging_dir(root) as staging:
        with _minari_root(staging), warnings.catch_warnings():
            # author, permalink...: optional metadata Minari asks for
            warnings.simplefilter("ignore", UserWarning)
            ds = minari.create_dataset_from_buffers(
                dataset_id,
                buffers,
                env=_recordable_env(env),
                action_space=env.action_space,
                observation_space=env.observation_space,
                algorithm_name=algorithm_name,
                author="scorbot-gym",
                description=description,
                code_permalink="https://github.com/scorbot-gym (scorbot_gym/rl/datasets.py)",
                data_format="hdf5",
                jpeg_encoding=False,  # Minari's default JPEG-compresses images: lossy
            )
            ds.storage.update_metadata({SETTINGS_KEY: recorded})
        _move_namespace_records(staging, root, parse_dataset_id(dataset_id)[0])
        check_dataset_id(dataset_id, "dataset")  # taken meanwhile? (rename would merge into it)
        os.rename(staging / dataset_id, target)
    return minari.load_dataset(dataset_id)


def record_demonstrations(
    dataset_id: str,
    episodes: int,
    pose: str = "oracle",
    seed: int | None = None,
    dart_sigma: float = 0.0,
    pose_kwargs: dict[str, Any] | None = None,
    progress: Callable[[int, int], None] | None = None,
    identity: str | None = None,
    **env_kwargs: Any,
):
    """Run ``episodes`` scripted episodes (seeds ``seed, seed + 1, ...``; default the start of
    :data:`scorbot_gym.seeds.DEMONSTRATIONS`, and a warning if they lie in an evaluation
    range) on the wrapped env with pose source ``pose`` and store them as a Minari dataset.
    The controller acts on the oracle pose whatever ``pose`` is (it is the demonstrator); the
    observations carry what the pose source estimated. ``identity`` (``pose="manifold"``
    only): ``"recognize"`` (default: the estimator recognises the object from the top and side
    views, no privileged input, as ``rollout --pose manifold``) or ``"given"`` (privileged: it
    is told the true class); the settings record it. Returns the ``MinariDataset``."""
    from scorbot_gym.envs.factory import make_env
    from scorbot_gym.rl.provenance import env_pose_models, seed_span

    if pose not in POSES:
        raise ValueError(f"pose must be one of {POSES}, got {pose!r}")
    if identity not in (None, *IDENTITIES):
        raise ValueError(f"identity must be one of {IDENTITIES}, got {identity!r}")
    if pose != "manifold" and identity is not None:
        raise ValueError(f"identity only applies to pose 'manifold', not {pose!r}")
    if pose == "manifold":
        identity = identity or "recognize"
    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}")
    seed = seed_ranges.DEMONSTRATIONS.start if seed is None else int(seed)
    _warn_evaluation_seeds(range(seed, seed + episodes))
    with reserve_dataset_id(dataset_id):  # checked and held before any episode runs
        if pose == "manifold" and not pose_kwargs:
            from scorbot_gym.evaluation.rollout import RolloutConfig

            recognize = identity == "recognize"
            pose_kwargs = RolloutConfig(pose="manifold", recognize=recognize).pose_kwargs()
        env_kwargs.setdefault("env_id", "ScorbotGraspCartesian-v0")
        env = make_env(
            pose=pose, pose_kwargs=pose_kwargs, identity=identity or "given", **env_kwargs
        )
        rng = np.random.default_rng(seed)
        try:
            data = []
            for i in range(episodes):
                data += collect_episodes(env, [seed + i], dart_sigma=dart_sigma, rng=rng)
                if progress:
                    progress(i + 1, episodes)
            success = float(np.mean([ep.success for ep in data]))
            description = (
                f"{episodes} scripted grasping episodes (seeds {seed}..{seed + episodes - 1}), "
                f"pose source {pose!r}, DART sigma {dart_sigma}, success {success:.1%}; "
                f"infos[{LABEL_KEY!r}] is the controller's clean action given the oracle pose"
            )
            settings = {
                "env_id": env_kwargs["env_id"],
                "pose": pose,
                **({"identity": identity} if pose == "manifold" else {}),
                "pose_models": env_pose_models(env),
                "seeds": seed_span(range(seed, seed + episodes)),
                "dart_sigma": float(dart_sigma),
                "success_rate": success,
            }
            return write_dataset(dataset_id, data, env, description=description, settings=settings)
        finally:
            env.close()


def _warn_evaluation_seeds(seeds: range) -> None:
    """Demonstrations on evaluation seeds teach the placements a policy is judged on."""
    for r in seed_ranges.EVALUATION_RANGES:
        if seeds.start < r.stop and r.start < seeds.stop:
            warnings.warn(
                f"demonstration seeds {seeds.start}..{seeds.stop - 1} overlap the evaluation "
                f"range {r.name!r} [{r.start}, {r.stop}) ({r.use}); a policy trained on them "
                f"is judged on its training placements there",
                stacklevel=3,
            )


def read_dataset(dataset: Any) -> DemonstrationSet:
    """The episodes of a Minari dataset (an id or a loaded ``MinariDataset``) with the settings
    they were recorded with (:data:`SETTINGS_KEY`; a dataset recorded before them has only
    ``dataset_id`` and ``sha256``), the dataset's id and the SHA-256 of its files."""
    import minari

    from scorbot_gym.rl.provenance import folder_sha256

    ds = minari.load_dataset(dataset) if isinstance(dataset, str) else dataset
    settings = dict(ds.storage.metadata.get(SETTINGS_KEY) or {})
    settings["dataset_id"] = ds.spec.dataset_id
    settings["sha256"] = folder_sha256(ds.storage.data_path)
    return DemonstrationSet(load_demonstrations(ds), settings)


def load_demonstrations(dataset: Any) -> list[LabelledEpisode]:
    """The episodes of a Minari dataset (an id or a loaded ``MinariDataset``) written by
    :func:`record_demonstrations`; a dataset without expert labels is a one-line error.
    :func:`read_dataset` gives them with the settings they were recorded with."""
    import minari

    ds = minari.load_dataset(dataset) if isinstance(dataset, str) else dataset
    out = []
    seeds = {
        int(m["id"]): m.get("seed") for m in ds.storage.get_episode_metadata(ds.episode_indices)
    }
    for ep in ds.iterate_episodes():
        infos = dict(ep.infos)
        if LABEL_KEY not in infos:
            raise ValueError(
                f"dataset {ds.spec.dataset_id!r} has no infos[{LABEL_KEY!r}] (expert labels); "
                "record it with `scorbot-gym demos`"
            )
        labels = infos.pop(LABEL_KEY)
        out.append(
            LabelledEpisode(
                seed=int(ep.id if seeds.get(int(ep.id)) is None else seeds[int(ep.id)]),
                observations={k: np.asarray(v) for k, v in ep.observations.items()},
                actions=np.asarray(ep.actions, np.float32),
                labels=np.asarray(labels, np.float32),
                rewards=np.asarray(ep.rewards, np.float64),
                terminations=np.asarray(ep.terminations, bool),
                truncations=np.asarray(ep.truncations, bool),
                infos={k: np.asarray(v) for k, v in infos.items()},
            )
        )
    return out
