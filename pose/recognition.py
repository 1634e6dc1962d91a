"""Which object is in view: from silhouettes (one or more cameras) or from appearance.

Two recognisers with one answer type, :class:`Recognition`:

- :class:`SilhouetteRecognizer`: a shape classifier per camera (FLR by default) on the
  object's mask; with several cameras their class costs are fused. One camera alone is often
  ambiguous (from straight above, cans, cylinder and balls are all discs), and the cameras'
  ambiguities differ, so fusing them resolves most of it.
- :class:`AppearanceRecognizer`: run every object's pose model on the view and take the one
  whose keypoint matching explains the most RANSAC inliers. It needs texture, not an outline,
  so a half-hidden object is still recognised from what is left of it; when too few
  keypoints are left for any pose, :class:`DescriptorVoteRecognizer` (nearest training
  descriptor across all objects, ratio-tested) answers instead.
- :class:`ShortlistRecognizer`: the silhouette classifier's few best classes, decided among
  by appearance.

:class:`RecognitionMemory` is the policy for using either in a control loop: the arm itself
hides the object during a grasp, so recognise while the view is clear (silhouette away from
the image border and the arm, confident margin), keep that answer and stop asking.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from sklearn.base import BaseEstimator, clone

from pose.features.keypoints import extract_sift
from pose.features.matching import DescriptorIndex
from pose.shape.descriptors import shape_descriptor
from pose.shape.flr import FLRClassifier

_EPS = 1e-9


@dataclass(frozen=True)
class Recognition:
    """A recognised class with per-class costs (lower is better) and the best-vs-runner-up margin.

    ``label`` is ``None`` when nothing could be recognised (no mask, no valid estimate).
    ``margin`` is ``cost(runner-up) - cost(best)`` (>= 0; 0 when there is no runner-up).
    ``estimates`` holds per-class pose estimates when the recogniser made them (appearance).
    """

    label: str | None
    costs: dict[str, float] = field(default_factory=dict)
    margin: float = 0.0
    estimates: dict[str, Any] = field(default_factory=dict, repr=False)

    @classmethod
    def from_costs(cls, costs: Mapping[str, float], **kwargs: Any) -> Recognition:
        finite = {k: float(v) for k, v in costs.items() if np.isfinite(v)}
        if not finite:
            return cls(None, dict(costs), 0.0, **kwargs)
        order = sorted(finite, key=finite.get)
        margin = finite[order[1]] - finite[order[0]] if len(order) > 1 else 0.0
        return cls(order[0], dict(costs), float(margin), **kwargs)


def _class_costs(classifier: Any, x: np.ndarray) -> np.ndarray:
    """Per-class costs of one descriptor, ``log`` of the distance relative to the nearest class.

    FLR gives IN distances; their scale differs between cameras, so each camera's distances are
    divided by their minimum (the best class costs 0) before fusion. Probabilistic classifiers
    give ``-log p`` instead.
    """
    if hasattr(classifier, "class_distances"):
        d = np.asarray(classifier.class_distances(x)[0], float)
        return np.log((d + _EPS) / (d.min() + _EPS))
    if hasattr(classifier, "predict_proba"):
        p = np.asarray(classifier.predict_proba(x)[0], float)
        return -np.log(p + _EPS) + np.log(p.max() + _EPS)
    raise TypeError(
        f"{type(classifier).__name__} gives no class scores: it needs class_distances (FLR) "
        "or predict_proba"
    )


class SilhouetteRecognizer(BaseEstimator):
    """Shape classification of the object's silhouette, fused over cameras.

    Parameters
    ----------
    classifier : estimator, default ``FLRClassifier()``
        Cloned and fitted once per camera on that camera's silhouettes (a silhouette's shape
        depends on the viewpoint, so each camera gets its own). It must offer
        ``class_distances`` (FLR) or ``predict_proba``.
    featurize : callable
        Mask -> descriptor (default the 73-d :func:`pose.shape.descriptors.shape_descriptor`).

    Attributes
    ----------
    classifiers_ : dict camera -> fitted classifier
    classes_ : ndarray, the class labels (the same for every camera)
    """

    #: what ``recognize`` takes: ``{camera: mask}`` (appearance recognisers take a view)
    reads = "silhouettes"

    def __init__(
        self,
        classifier: Any = None,
        featurize: Callable[[np.ndarray], np.ndarray] = shape_descriptor,
    ) -> None:
        self.classifier = classifier
        self.featurize = featurize

    def fit(
        self, masks: Mapping[str, Sequence[np.ndarray]], labels: Mapping[str, Sequence[str]]
    ) -> SilhouetteRecognizer:
        """Fit one classifier per camera: ``masks[cam]`` silhouettes labelled ``labels[cam]``."""
        if not masks:
            raise ValueError("masks must map at least one camera name to its silhouettes")
        base = self.classifier if self.classifier is not None else FLRClassifier()
        self.classifiers_, classes = {}, None
        for cam, cam_masks in masks.items():
            y = np.asarray(labels[cam])
            if len(cam_masks) != len(y) or len(y) == 0:
                raise ValueError(
                    f"camera {cam!r}: {len(cam_masks)} masks but {len(y)} labels (need >= 1)"
                )
            X = np.stack([self.featurize(m) for m in cam_masks])
            clf = clone(base).fit(X, y)
            if classes is not None and not np.array_equal(clf.classes_, classes):
                raise ValueError(f"camera {cam!r} was trained on other classes than the others")
            classes = clf.classes_
            self.classifiers_[cam] = clf
        self.classes_ = classes
        return self

    @property
    def cameras(self) -> tuple[str, ...]:
        return tuple(getattr(self, "classifiers_", {}))

    def recognize(self, masks: Mapping[str, np.ndarray | None]) -> Recognition:
        """Recognise from the silhouettes of one or more cameras (``None``/empty ones skipped).

        Cameras without a fitted classifier are ignored; the fused cost is the sum of the
        cameras' relative log-distances.
        """
        total, used = np.zeros(len(self.classes_)), 0
        for cam, mask in masks.items():
            if cam not in self.classifiers_ or mask is None or not np.any(mask):
                continue
            try:
                x = np.asarray(self.featurize(np.asarray(mask, bool)), float)[None, :]
            except ValueError:  # too few pixels to describe a shape
                continue
            total += _class_costs(self.classifiers_[cam], x)
            used += 1
        if used == 0:
            return Recognition(None)
        return Recognition.from_costs(
            dict(zip(map(str, self.classes_), total.tolist(), strict=True))
        )


class DescriptorVoteRecognizer:
    """The class whose training descriptors are nearest to most of the view's SIFT descriptors.

    Each keypoint votes for the object owning its nearest training descriptor (pooled over
    all objects' fitted ``db_desc_``) if that is closer than ``ratio`` times the nearest
    descriptor of any *other* object (Lowe's ratio test across objects: descriptors repeated
    over one object's own training views must not cancel each other). No geometry, so it
    still answers with a handful of keypoints, where a pose estimate needs more.
    """

    reads = "view"

    def __init__(
        self, estimators: Mapping[str, Any], ratio: float = 0.8, k: int = 10, seed: int = 0
    ) -> None:
        if not estimators:
            raise ValueError("estimators must map at least one class to a fitted estimator")
        if not 0.0 < ratio <= 1.0:
            raise ValueError(f"ratio must be in (0, 1], got {ratio!r}")
        self.estimators, self.ratio, self.k, self.seed = dict(estimators), ratio, k, seed
        self._index: DescriptorIndex | None = None

    def _build(self) -> DescriptorIndex:
        names = list(self.estimators)
        descs = [np.asarray(self.estimators[n].db_desc_, np.float32) for n in names]
        ids = np.concatenate([np.full(len(d), i) for i, d in enumerate(descs)])
        self._names = names
        self._contrast = float(getattr(self.estimators[names[0]], "contrast_threshold", 0.04))
        return DescriptorIndex(np.concatenate(descs), ids, len(names), self.seed)

    def recognize(self, view: Any) -> Recognition:
        if self._index is None:
            self._index = self._build()
        f = extract_sift(view.image, view.mask, 0, self._contrast)
        votes = np.zeros(len(self._names))
        if len(f):
            idx, dist = self._index.nearest(f.descriptors, self.k)
            owner = np.where(idx >= 0, self._index.view_ids[np.maximum(idx, 0)], -1)
            for row_owner, row_dist in zip(owner, dist, strict=True):
                if row_owner[0] < 0:
                    continue
                other = row_dist[(row_owner != row_owner[0]) & (row_owner >= 0)]
                d2 = other[0] if len(other) else np.inf
                if row_dist[0] < self.ratio * d2:
                    votes[row_owner[0]] += 1
        costs = {n: (-v if v > 0 else np.inf) for n, v in zip(self._names, votes, strict=True)}
        return Recognition.from_costs(costs)


class AppearanceRecognizer:
    """The class whose pose model explains the most keypoints of the view (RANSAC inliers).

    ``estimators`` maps class -> a fitted estimator with ``predict(view)`` returning an object
    with ``valid`` and ``n_inliers`` (e.g. :class:`pose.manifold.estimator.PoseManifoldEstimator`).
    The cost of a class is ``-n_inliers`` (``inf`` when its estimate is invalid); the winning
    class's estimate comes back in :attr:`Recognition.estimates`, so it need not be re-run.
    When no class gives a valid estimate (too few keypoints left, e.g. a small object half
    hidden) the ``fallback`` recogniser answers (default :class:`DescriptorVoteRecognizer`
    when the estimators keep their training descriptors; ``None``: no answer).
    """

    reads = "view"

    def __init__(self, estimators: Mapping[str, Any], fallback: Any = "votes") -> None:
        if not estimators:
            raise ValueError("estimators must map at least one class to a pose estimator")
        self.estimators = dict(estimators)
        if isinstance(fallback, str):
            if fallback != "votes":
                raise ValueError(
                    f"fallback must be 'votes', None or a recognizer, got {fallback!r}"
                )
            has_db = all(hasattr(e, "db_desc_") for e in self.estimators.values())
            fallback = DescriptorVoteRecognizer(self.estimators) if has_db else None
        self.fallback = fallback

    def recognize(self, view: Any, classes: Sequence[str] | None = None) -> Recognition:
        """The best class among ``classes`` (default: all), by RANSAC inliers."""
        costs, estimates = {}, {}
        names = list(self.estimators) if classes is None else list(classes)
        for name in names:
            est = self.estimators[name]
            v = view
            if dataclasses.is_dataclass(view) and hasattr(view, "object_name"):
                v = dataclasses.replace(view, object_name=name)
            out = est.predict(v)
            estimates[name] = out
            costs[name] = -float(out.n_inliers) if out.valid else np.inf
        result = Recognition.from_costs(costs, estimates=estimates)
        if result.label is None and self.fallback is not None and classes is None:
            voted = self.fallback.recognize(view)
            return dataclasses.replace(voted, estimates=estimates)
        return result


class ShortlistRecognizer:
    """Silhouettes shortlist, appearance decides: FLR's ``k`` best classes are checked by their
    pose models, and the one explaining the most RANSAC inliers wins.

    The silhouette classifier is cheap and usually right (its misses are classes of similar
    outline: a disc from above is a can, a ball or a cylinder), while appearance tells such
    classes apart by their texture but costs one pose estimate per class. Asking appearance
    only about the shortlist keeps the shape classifier in charge of what is plausible and
    costs ``k`` estimates instead of one per catalogue object. When no shortlisted class gives
    a valid estimate (too few keypoints), the silhouette answer stands.

    ``recognize(masks, view)`` takes both inputs (``reads == "silhouettes+view"``).
    """

    reads = "silhouettes+view"

    def __init__(self, silhouettes: Any, appearance: AppearanceRecognizer, k: int = 3) -> None:
        if int(k) < 1:
            raise ValueError(f"k (shortlist length) must be >= 1, got {k!r}")
        self.silhouettes, self.appearance, self.k = silhouettes, appearance, int(k)

    def recognize(self, masks: Mapping[str, np.ndarray | None], view: Any) -> Recognition:
        shape = self.silhouettes.recognize(masks)
        if shape.label is None:
            return self.appearance.recognize(view)
        finite = {c: v for c, v in shape.costs.items() if np.isfinite(v)}
        shortlist = sorted(finite, key=finite.get)[: self.k]
        checked = self.appearance.recognize(view, classes=shortlist)
        return checked if checked.label is not None else shape


def view_is_clear(
    mask: np.ndarray | None,
    exclude_mask: np.ndarray | None = None,
    min_area: int = 200,
    gap: int = 3,
) -> bool:
    """Whether a silhouette is complete enough to recognise from.

    It must have ``min_area`` pixels, keep ``gap`` pixels off the image border (else it may be
    cut off) and ``gap`` pixels off ``exclude_mask`` (the arm: it may hide part of it).
    """
    if mask is None:
        return False
    m = np.asarray(mask, bool)
    if m.sum() < min_area:
        return False
    g = max(int(gap), 1)
    if m[:g].any() or m[-g:].any() or m[:, :g].any() or m[:, -g:].any():
        return False
    if exclude_mask is not None:
        grown = cv2.dilate(m.astype(np.uint8), np.ones((2 * g + 1, 2 * g + 1), np.uint8)) > 0
        if np.any(grown & np.asarray(exclude_mask, bool)):
            return False
    return True


class RecognitionMemory:
    """Recognise once while the view is clear, then keep the answer for the episode.

    ``offer(result, clear)`` accepts ``result`` if the view was clear and its margin is at
    least ``min_margin`` (in the recogniser's cost units); once accepted, the label is kept
    until :meth:`reset`. Until then :meth:`label_for` answers the step's own best guess, which
    is used but not kept.
    """

    def __init__(self, min_margin: float = 0.0) -> None:
        if not np.isfinite(min_margin) or min_margin < 0:
            raise ValueError(f"min_margin must be a finite number >= 0, got {min_margin!r}")
        self.min_margin = float(min_margin)
        self.kept: Recognition | None = None

    def reset(self) -> None:
        self.kept = None

    def offer(self, result: Recognition, clear: bool) -> bool:
        """Keep ``result`` if it qualifies and nothing is kept yet; True if it was kept."""
        if self.kept is not None or result.label is None or not clear:
            return False
        if result.margin < self.min_margin:
            return False
        self.kept = result
        return True

    def label_for(self, result: Recognition | None) -> str | None:
        if self.kept is not None:
            return self.kept.label
        return None if result is None else result.label
