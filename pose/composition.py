"""What the estimators built from other estimators share: fitting, scoring, their files.

:class:`~pose.fallback.ConfidenceFallback` and :class:`~pose.selection.ValidationSelection`
hold fitted estimators as parts. Both score like every estimator, and both store their parts
in one pickle-free file, each part under its own prefix and rebuilt from its class name, so
that a composition can hold any registered estimator, another composition included.
"""

from __future__ import annotations

import inspect
import os
from collections.abc import Sequence

from pose.metrics import ScoredEstimator
from pose.serialization import load_estimator_arrays, save_arrays
from pose.symmetry import Symmetry
from pose.view import View


def _loadable_classes() -> dict[str, type]:
    """Estimator classes a composition's file may hold, by class name."""
    from pose import baselines
    from pose.fallback import ConfidenceFallback
    from pose.manifold.estimator import PoseManifoldEstimator
    from pose.selection import ValidationSelection

    classes = [PoseManifoldEstimator, ConfidenceFallback, ValidationSelection]
    classes += [getattr(baselines, name) for name in baselines.__all__]
    return {c.__name__: c for c in classes}


def fit_estimator(est, views: Sequence[View], poses, symmetry: Symmetry | None = None):
    """``est.fit(views, poses)``, passing the object's ``symmetry`` to estimators whose ``fit``
    takes it (a :class:`~pose.selection.ValidationSelection` scores its candidates with it);
    returns the fitted estimator."""
    if symmetry is not None and "symmetry" in inspect.signature(est.fit).parameters:
        return est.fit(views, poses, symmetry=symmetry)
    return est.fit(views, poses)


def load_part(class_name: str, arrays: dict, prefix: str, format_version: int | None):
    """A fitted part of a composition's file, by its class name (the versioned classes also
    get the file's format version)."""
    part_cls = _loadable_classes()[class_name]
    if "format_version" in inspect.signature(part_cls.from_arrays).parameters:
        return part_cls.from_arrays(arrays, prefix, format_version)
    return part_cls.from_arrays(arrays, prefix)


class Composition(ScoredEstimator):
    """``score``, ``save`` and ``load`` for an estimator with ``predict``, ``to_arrays`` and
    ``from_arrays(arrays, prefix, format_version)``."""

    def save(self, path: str | os.PathLike) -> None:
        """The fitted parts in one ``.npz`` (atomic, pickle-free, versioned)."""
        save_arrays(path, self.to_arrays(), {"kind": "estimator", "class": type(self).__name__})

    @classmethod
    def load(cls, path: str | os.PathLike):
        header, arrays = load_estimator_arrays(path, cls.__name__)
        return cls.from_arrays(arrays, format_version=header["format_version"])
