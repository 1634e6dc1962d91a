"""How an env's spec names a pose source's arguments, so that ``gym.make(env.spec)`` rebuilds it.

A spec holds plain data: Gymnasium deep-copies it, compares it, prints it and writes it as
JSON. A loaded :class:`pose.model_set.PoseModelSet` (up to tens of MB) is therefore recorded by
a reference that reloads it, never as the object (nor a pickle of it): the file it was read
from, while that file is unchanged (:func:`load_model_set` and :func:`default_models` remember
it), or else a copy in the cache named by its content digest
(``<cache>/models/content/<sha256>.npz``, written once per content, when a spec first needs
it). Anything else that is not plain data cannot be recorded: the spec then says which
argument, and re-making from it refuses in one line instead of building another source.

This lives here, not in :mod:`pose.model_set`: the ``pose`` package's source is part of the
default models' cache key, and a spec is the env's business.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
import weakref
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from pose.model_set import PoseModelSet

CONTENT_FOLDER = ("models", "content")

# model set -> (the file that holds it, that file's size and modification time when read)
_FILES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


class NotRecordable(ValueError):
    """A pose-source argument that an env spec cannot hold."""


def spec_value(value: Any) -> Any:
    """``value`` as plain spec data: itself if plain, a model set by its file's path, a list
    or tuple element by element; :class:`NotRecordable` otherwise."""
    if isinstance(value, (str, int, float, bool, type(None))):
        return value
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    if isinstance(value, (list, tuple)):
        return type(value)(spec_value(v) for v in value)
    if _is_model_set(value):
        return model_set_reference(value)
    raise NotRecordable(type(value).__name__)


def spec_kwargs(kwargs: Mapping[str, Any]) -> tuple[dict[str, Any], list[str]]:
    """The recordable ``kwargs`` as spec data, and ``"name (type)"`` of those that are not."""
    recorded, left_out = {}, []
    for key, value in kwargs.items():
        try:
            recorded[key] = spec_value(value)
        except NotRecordable as exc:
            left_out.append(f"{key} ({exc})")
    return recorded, left_out


def load_model_set(path: str | os.PathLike) -> PoseModelSet:
    """``PoseModelSet.load(path)``, remembered as that file's (for the spec's reference)."""
    from pose.model_set import PoseModelSet

    models = PoseModelSet.load(path)
    remember_file(models, path)
    return models


def default_models(
    camera: str = "top", width: int = 320, height: int = 240, **kwargs: Any
) -> PoseModelSet:
    """:func:`~scorbot_gym.perception.training.default_pose_models` (same arguments),
    remembered as its cache file's, so a spec names that file instead of copying it."""
    from scorbot_gym.perception import training

    models = training.default_pose_models(camera, width, height, **kwargs)
    keys = ("objects", "seed", "cache_dir", "training")
    path = training.default_models_path(
        camera, width, height, **{k: v for k, v in kwargs.items() if k in keys}
    )
    if _file_holds(path, models):
        remember_file(models, path)
    return models


def remember_file(models: PoseModelSet, path: str | os.PathLike) -> None:
    """Take ``path``, a file that holds exactly ``models``, as the set's reference."""
    path = Path(path).resolve()
    _FILES[models] = (path, _stamp(path))


def saved_path(models: PoseModelSet) -> Path | None:
    """The file remembered for ``models`` while it is unchanged (same size and modification
    time), else ``None``: an overwritten file no longer holds the set."""
    path, stamp = _FILES.get(models, (None, None))
    try:
        return path if path is not None and _stamp(path) == stamp else None
    except OSError:
        return None


def content_digest(models: PoseModelSet) -> str:
    """SHA-256 (hex) of a model set's content: its objects, estimator classes, meta and every
    array's name, dtype, shape and bytes. Equal sets have equal digests however often they are
    saved (the ``.npz`` bytes themselves carry zip timestamps), so a cache can be keyed by it."""
    names = models.object_names
    header = {
        "objects": names,
        "classes": [type(models.estimators[n]).__name__ for n in names],
        "meta": models.meta,
    }
    h = hashlib.sha256(json.dumps(header, sort_keys=True, default=str).encode())
    for i, name in enumerate(names):
        arrays = models.estimators[name].to_arrays(prefix=f"o{i}/")
        for key in sorted(arrays):
            a = np.ascontiguousarray(arrays[key])
            h.update(f"\0{key}\0{a.dtype.str}\0{a.shape}\0".encode())
            h.update(a.tobytes())
    return h.hexdigest()


def model_set_reference(models: PoseModelSet) -> str:
    """The absolute path of a file that holds ``models``: the one remembered for it while
    unchanged, else its content-addressed copy in the cache (written if missing)."""
    saved = saved_path(models)
    if saved is not None:
        return os.fspath(saved)
    from scorbot_gym.data import default_cache_dir

    target = default_cache_dir().joinpath(*CONTENT_FOLDER, f"{content_digest(models)}.npz")
    if not target.is_file():
        models.save(target)  # atomic: a concurrent writer of the same content is harmless
    remember_file(models, target)
    return os.fspath(target.resolve())


def _file_holds(path: Path, models: PoseModelSet) -> bool:
    """Whether the model file ``path`` names ``models``'s objects and meta (its header only,
    read without the arrays): cheap evidence that it is the file the set was read from."""
    if not path.is_file():
        return False
    try:
        with np.load(path, allow_pickle=False) as z:
            header = json.loads(str(z["__header__"]))
    except Exception:  # noqa: BLE001 - an unreadable file holds nothing
        return False
    meta = json.loads(json.dumps(models.meta, default=str))  # as a file holds it (no tuples)
    return header.get("objects") == models.object_names and header.get("meta") == meta


def _stamp(path: Path) -> tuple[int, int]:
    st = path.stat()
    return st.st_size, st.st_mtime_ns


def _is_model_set(value: Any) -> bool:
    """Whether ``value`` is a ``PoseModelSet`` (if its module is not imported, it is not one:
    asking does not pull in OpenCV and scikit-learn)."""
    module = sys.modules.get("pose.model_set")
    return module is not None and isinstance(value, module.PoseModelSet)
