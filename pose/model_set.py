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

import json
import os
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
        arrays: dict[str, np.ndarray] = {}
        for i, name in enumerate(self.object_names):
            arrays.update(self.estimators[name].to_arrays(prefix=f"o{i}/"))
        classes = [type(self.estimators[n]).__name__ for n in self.object_names]
        header = {"kind": "model_set", "objects": self.object_names, "meta": self.meta}
        if any(c != PoseManifoldEstimator.__name__ for c in classes):
            header["classes"] = classes  # absent: all manifolds (files of earlier versions too)
        save_arrays(path, arrays, header)

    @classmethod
    def load(cls, path: str | os.PathLike) -> PoseModelSet:
        header, arrays = load_arrays(path)
        version = header["format_version"]
        if header.get("kind") == "estimator":
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
        return cls(estimators, header.get("meta") or {})
