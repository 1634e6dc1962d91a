"""How an env's spec names a pose source's arguments, so that ``gym.make(env.spec)`` rebuilds it.

A spec holds plain data: Gymnasium deep-copies it, compares it, prints it and writes it as
JSON. A loaded :class:`pose.model_set.PoseModelSet` (tens of MB) is therefore recorded by a
reference that reloads it, never as the object (nor a pickle of it): the file it was loaded
from or saved to, or, for a set that lives only in memory (``train_models(...)``), a copy in
the cache named by its content digest (``<cache>/models/content/<sha256>.npz``, written once
per content). Anything else that is not plain data cannot be recorded; the spec then says
which argument, and re-making from it refuses in one line instead of building another source.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Mapping
from typing import Any

CONTENT_FOLDER = ("models", "content")


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


def model_set_reference(models: Any) -> str:
    """The absolute path of a file that holds ``models``: the one it was loaded from or saved
    to while unchanged, else its content-addressed copy in the cache (written if missing)."""
    saved = models.saved_path()
    if saved is not None:
        return os.fspath(saved)
    from scorbot_gym.data import default_cache_dir

    target = default_cache_dir().joinpath(*CONTENT_FOLDER, f"{models.content_digest()}.npz")
    if target.is_file():
        models.remember_file(target)  # the same content: this set is that file's
    else:
        models.save(target)
    return os.fspath(models.path)


def _is_model_set(value: Any) -> bool:
    """Whether ``value`` is a ``PoseModelSet`` (if its module is not imported, it is not one:
    asking does not pull in OpenCV and scikit-learn)."""
    module = sys.modules.get("pose.model_set")
    return module is not None and isinstance(value, module.PoseModelSet)
