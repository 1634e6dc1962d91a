"""Recognise the object from its silhouette, then estimate its pose with that object's model.

Integration choice: *per-class pose models*, not a class feature. A pose manifold is learned
per object (each object has its own appearance manifold and its own symmetry group), so one
regressor with a class input would have to interpolate between unrelated manifolds, and
adding an object would mean retraining everything. With per-class models the recogniser picks
the model and each model stays small and independently trainable.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from pose.shape.descriptors import shape_descriptor


class ViewPredictor(Protocol):
    """Anything with ``predict(view)``, e.g. ``pose.manifold.estimator.PoseManifoldEstimator``."""

    def predict(self, view: Any) -> Any: ...


@dataclass(frozen=True)
class Recognition:
    """The recognised class, that class's pose estimate and the classifier's class scores."""

    label: Any
    estimate: Any
    class_distances: dict[Any, float] | None = None


def default_mask_of(view: Any) -> np.ndarray:
    """The silhouette of ``view``: its ``.mask`` attribute, or the view itself if an array."""
    if isinstance(view, np.ndarray):
        return view
    mask = getattr(view, "mask", None)
    if mask is None:
        raise ValueError(
            "the view has no silhouette: give it a .mask (HxW bool, e.g. the simulator's "
            "segmentation render) or pass mask_of= to RecognizeThenEstimate"
        )
    return np.asarray(mask)


class RecognizeThenEstimate:
    """Shape classifier + one pose estimator per class.

    Parameters
    ----------
    classifier
        A fitted classifier on shape descriptors (``predict(X)`` with X ``(n, 73)``), e.g.
        :class:`pose.shape.flr.FLRClassifier`. If it has ``class_distances`` (FLR) or
        ``decision_function``, the scores are reported in :class:`Recognition`.
    estimators
        ``{class label: estimator}``; each estimator only needs ``predict(view)``.
    mask_of
        How to get the silhouette out of a view (default: ``view.mask``).
    featurize
        Silhouette -> descriptor vector; must match what the classifier was trained on.
    """

    def __init__(
        self,
        classifier: Any,
        estimators: Mapping[Any, ViewPredictor],
        mask_of: Callable[[Any], np.ndarray] = default_mask_of,
        featurize: Callable[[np.ndarray], np.ndarray] = shape_descriptor,
    ) -> None:
        if not estimators:
            raise ValueError("estimators must map at least one class label to a pose estimator")
        for label, est in estimators.items():
            if not callable(getattr(est, "predict", None)):
                raise TypeError(f"estimator for class {label!r} has no predict(view) method")
        self.classifier = classifier
        self.estimators = dict(estimators)
        self.mask_of = mask_of
        self.featurize = featurize

    def recognize(self, view: Any) -> tuple[Any, dict[Any, float] | None]:
        """Class label of ``view`` and, when the classifier offers them, per-class scores."""
        x = np.asarray(self.featurize(self.mask_of(view)), dtype=np.float64)[None, :]
        label = self.classifier.predict(x)[0]
        scores = None
        classes = getattr(self.classifier, "classes_", None)
        if classes is not None and hasattr(self.classifier, "class_distances"):
            scores = dict(zip(classes, self.classifier.class_distances(x)[0].tolist(), strict=True))
        elif classes is not None and hasattr(self.classifier, "decision_function"):
            raw = np.atleast_1d(self.classifier.decision_function(x)[0])
            if raw.shape == (len(classes),):
                scores = dict(zip(classes, raw.tolist(), strict=True))
        label = label.item() if isinstance(label, np.generic) else label
        return label, scores

    def predict(self, view: Any) -> Recognition:
        """Recognise the object in ``view``, then run that class's pose estimator on it.

        If the view is a dataclass with an ``object_name`` field (``pose.view.View``), the
        estimator receives a copy naming the recognised class.
        """
        label, scores = self.recognize(view)
        if label not in self.estimators:
            raise KeyError(
                f"recognised class {label!r} has no pose estimator; estimators exist for: "
                f"{', '.join(map(repr, self.estimators))}"
            )
        if dataclasses.is_dataclass(view) and any(
            f.name == "object_name" for f in dataclasses.fields(view)
        ):
            view = dataclasses.replace(view, object_name=str(label))
        return Recognition(label, self.estimators[label].predict(view), scores)
