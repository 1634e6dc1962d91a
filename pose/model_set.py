"""Several objects' estimators in one model file.

Each object gets its own :class:`PoseManifoldEstimator`: objects differ in texture, size and
symmetry, so one manifold per object stays low-dimensional and a new object can be added
without retraining the others. The object is chosen by ``View.object_name`` (given by the
scene, or by the shape recognizer). A set may also hold any other registered estimator with
``to_arrays`` / ``from_arrays`` (a baseline, ``chance``, a composition): the file names each
object's class, so a baseline's model set runs in the closed loop exactly where the manifold's
does (``ModelSetPoseSource``); files without class names hold manifolds.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from pose.composition import load_part
from pose.manifold.estimator import PoseManifoldEstimator
from pose.serialization import load_arrays, save_arrays
from pose.view import PoseEstimate, View


class PoseModelSet:
    """Mapping ``object name -> fitted estimator`` (a :class:`PoseManifoldEstimator` unless
    told otherwise) with one-file save/load."""

    def __init__(self, estimators: dict[str, Any] | None = None, meta: dict | None = None):
        self.estimators: dict[str, Any] = dict(estimators or {})
        self.meta: dict = dict(meta or {})  # how the training views were made (camera, size...)
        #: the file this set was loaded from or last saved to (absolute), ``None`` if neither:
        #: how an env's spec names the set, so that ``gym.make(spec)`` reloads it
        self.path: Path | None = None
        self._stamp: tuple[int, int] | None = None  # the file's (size, mtime) when it was read

    def saved_path(self) -> Path | None:
        """:attr:`path` while that file is still the one read or written (same size and
        modification time), else ``None``: an overwritten file no longer holds this set."""
        if self.path is None:
            return None
        try:
            return self.path if _stamp(self.path) == self._stamp else None
        except OSError:
            return None

    def remember_file(self, path: str | os.PathLike) -> None:
        """Take ``path`` (a file that holds exactly this set) as the set's :attr:`path`."""
        self.path = Path(path).resolve()
        self._stamp = _stamp(self.path)

    @property
    def object_names(self) -> list[str]:
        return sorted(self.estimators)

    def __getitem__(self, name: str) -> Any:
        if name not in self.estimators:
            raise KeyError(f"no pose model for object {name!r}; this file has {self.object_names}")
        return self.estimators[name]

    def predict(self, view: View) -> PoseEstimate:
        if view.object_name is None:
            if len(self.estimators) != 1:
                raise ValueError(
                    f"view.object_name is required with several objects: {self.object_names}"
                )
            return next(iter(self.estimators.values())).predict(view)
        return self[view.object_name].predict(view)

    def save(self, path: str | os.PathLike, meta: dict | None = None) -> None:
        """One ``.npz`` for all objects (atomic, pickle-free); ``meta`` must be JSON-able."""
        if meta is not None:
            self.meta = dict(meta)
        header, arrays = self._contents()
        self.remember_file(save_arrays(path, arrays, header))

    def _contents(self) -> tuple[dict, dict[str, np.ndarray]]:
        """The file's header and arrays, as :meth:`save` writes them."""
        arrays: dict[str, np.ndarray] = {}
        for i, name in enumerate(self.object_names):
            arrays.update(self.estimators[name].to_arrays(prefix=f"o{i}/"))
        classes = [type(self.estimators[n]).__name__ for n in self.object_names]
        header = {"kind": "model_set", "objects": self.object_names, "meta": self.meta}
        if any(c != PoseManifoldEstimator.__name__ for c in classes):
            header["classes"] = classes  # absent: all manifolds (files of earlier versions too)
        return header, arrays

    def content_digest(self) -> str:
        """SHA-256 (hex) of what :meth:`save` writes: the header and every array's name, dtype,
        shape and bytes. Equal sets have equal digests whenever and wherever they were saved
        (the ``.npz`` bytes themselves carry zip timestamps), so a cache can be keyed by it."""
        header, arrays = self._contents()
        h = hashlib.sha256(json.dumps(header, sort_keys=True).encode())
        for key in sorted(arrays):
            a = np.ascontiguousarray(arrays[key])
            h.update(f"\0{key}\0{a.dtype.str}\0{a.shape}\0".encode())
            h.update(a.tobytes())
        return h.hexdigest()

    @classmethod
    def load(cls, path: str | os.PathLike) -> PoseModelSet:
        header, arrays = load_arrays(path)
        version = header["format_version"]
        if header.get("kind") == "estimator":  # a single estimator's file: not re-saved as one
            return cls({"object": PoseManifoldEstimator.from_arrays(arrays, "", version)})
        names = header.get("objects")
        if header.get("kind") != "model_set" or not isinstance(names, list):
            raise ValueError(f"{path}: not a pose model set (header {json.dumps(header)})")
        classes = header.get("classes") or [PoseManifoldEstimator.__name__] * len(names)
        try:
            estimators = {
                n: load_part(c, arrays, f"o{i}/", version)
                for i, (n, c) in enumerate(zip(names, classes, strict=True))
            }
        except KeyError as exc:
            raise ValueError(f"{path}: unknown estimator class {exc} in a pose model set") from exc
        except ValueError as exc:
            raise ValueError(f"{path}: {exc}") from exc
        loaded = cls(estimators, header.get("meta") or {})
        loaded.remember_file(path)
        return loaded


def _stamp(path: Path) -> tuple[int, int]:
    st = path.stat()
    return st.st_size, st.st_mtime_ns
