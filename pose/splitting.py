"""Splitting foreground blobs between the objects that touch or overlap in them.

Background subtraction on a table with several objects gives one connected component per
group of objects that touch in the image, not one per object. A splitter takes the image and
those components and returns **regions**, one per object it can tell apart, each with the
class that claimed it (where one did). Three splitters, one contract (``split(image,
components) -> list[Region]``), so that an ablation swaps one for another:

- :class:`WholeComponents`: every component is one region (no splitting: the baseline);
- :class:`KeypointWatershedSplitter`: keypoint-to-model assignment. Each component's SIFT
  keypoints vote, through one nearest-neighbour index pooled over every class's training
  descriptors (Lowe's ratio test across classes), for the classes they look like; each class
  with enough votes is verified geometrically by its own pose model (the keypoints its RANSAC
  homographies explain, :meth:`~pose.manifold.estimator.PoseManifoldEstimator.
  explained_keypoints`). Where two or more classes explain keypoints of one component, their
  keypoints seed a marker-based watershed on the image (the flood from each object's
  keypoints meets its neighbour's at the colour edge between them), which splits the
  component's pixels. A component that one class or none explains stays whole;
- :class:`DistanceWatershedSplitter`: the classical split without any model: peaks of the
  distance transform (the "necks" between touching convex shapes) seed a watershed on it.
  It splits a non-convex single object too, which is why it is not the default.

:class:`SplitMemory` wraps a splitter for a control loop: on a fixed camera most components
do not change from one step to the next (the distractors stand still; only what the arm
covers or moves changes), so a component nearly identical to one split earlier in the
episode keeps that split's seeds and only the watershed runs again.

Nothing here reads a simulator: images, masks and fitted pose models in, regions out.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from sklearn.base import BaseEstimator

from pose.features.keypoints import extract_sift, shared_keypoints
from pose.features.matching import DescriptorIndex


@dataclass(frozen=True)
class Region:
    """One object's pixels after splitting: ``mask`` (``HxW`` bool), the ``component`` (index
    into the splitter's input) it came from, the ``label`` of the class whose keypoints seeded
    it (``None`` where no class did: a component left whole), how many keypoints did
    (``n_seeds``) and the ``seed`` mask itself (``None`` for a component left whole)."""

    mask: np.ndarray
    component: int
    label: str | None = None
    n_seeds: int = 0
    seed: np.ndarray | None = None


def _check_components(image: np.ndarray, components: Sequence[np.ndarray]) -> None:
    h, w = np.asarray(image).shape[:2]
    for i, c in enumerate(components):
        if np.shape(c) != (h, w):
            raise ValueError(f"component {i} has shape {np.shape(c)}, the image is {(h, w)}")


class WholeComponents:
    """No splitting: each component is one region (what a pipeline without a splitter does)."""

    def split(
        self, image: np.ndarray, components: Sequence[np.ndarray], camera: Any = None
    ) -> list[Region]:
        _check_components(image, components)
        return [Region(np.asarray(c, bool), i) for i, c in enumerate(components)]


def _watershed(image: np.ndarray, component: np.ndarray, seeds: list[np.ndarray]) -> np.ndarray:
    """Labels ``(H, W)`` int (0 outside ``component``, ``k + 1`` for ``seeds[k]``'s region):
    a marker-based watershed on ``image`` (``HxWx3`` uint8, or a single channel replicated)
    from each seed mask, restricted to the component; its boundary pixels go to the nearest
    region."""
    img = np.asarray(image)
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    comp = np.asarray(component, bool)
    ys, xs = np.nonzero(comp)
    pad = 2
    y0, y1 = max(ys.min() - pad, 0), min(ys.max() + pad + 1, comp.shape[0])
    x0, x1 = max(xs.min() - pad, 0), min(xs.max() + pad + 1, comp.shape[1])
    crop = comp[y0:y1, x0:x1]
    markers = np.where(crop, 0, 1).astype(np.int32)  # 1: outside the component
    for k, s in enumerate(seeds):
        markers[s[y0:y1, x0:x1] & crop] = k + 2
    bgr = np.ascontiguousarray(img[y0:y1, x0:x1, ::-1], np.uint8)
    cv2.watershed(bgr, markers)
    labels = np.where(crop, markers - 1, 0)
    labels[labels < 0] = 0  # outside marker (0 after the shift) and boundaries (-2)
    unassigned = crop & (labels <= 0)
    if unassigned.any():  # boundary pixels: the region nearest each
        dists = [
            cv2.distanceTransform((labels != k + 1).astype(np.uint8), cv2.DIST_L2, 3)
            for k in range(len(seeds))
        ]
        nearest = np.argmin(np.stack(dists), axis=0) + 1
        labels[unassigned] = nearest[unassigned]
    out = np.zeros(comp.shape, np.int32)
    out[y0:y1, x0:x1] = labels
    return out


def _regions_from_labels(
    labels: np.ndarray,
    component: int,
    names: Sequence[str | None],
    n_seeds: Sequence[int],
    seeds: Sequence[np.ndarray],
    min_area: int,
) -> list[Region]:
    """One region per label with at least ``min_area`` pixels; a smaller one's pixels join the
    largest region it touches (a sliver is not an object)."""
    areas = np.bincount(labels.ravel(), minlength=len(names) + 1)[1:]
    keep = [k for k in range(len(names)) if areas[k] >= min_area]
    if not keep:
        keep = [int(np.argmax(areas))]
    for k in range(len(names)):
        if k in keep:
            continue
        small = labels == k + 1
        ring = cv2.dilate(small.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
        touching = [j for j in keep if np.any(ring & (labels == j + 1))]
        target = max(touching or keep, key=lambda j: areas[j])
        labels[small] = target + 1
    return [Region(labels == k + 1, component, names[k], int(n_seeds[k]), seeds[k]) for k in keep]


class KeypointWatershedSplitter(BaseEstimator):
    """Split components between the classes whose pose models explain their keypoints.

    ``fit(estimators)`` takes ``{class: fitted pose estimator}`` (each with training
    descriptors ``db_desc_`` and :meth:`explained_keypoints`, as
    :class:`~pose.manifold.estimator.PoseManifoldEstimator` has) and builds the pooled
    descriptor index once. ``split`` then, per component: extracts SIFT once, lets each
    keypoint vote for the class of its nearest training descriptor where that is nearer than
    ``ratio`` times the nearest descriptor of any other class, verifies the (at most
    ``max_candidates``) classes with at least ``min_votes`` votes by their own models' RANSAC
    inliers, and where at least two classes keep ``min_seeds`` keypoints that no other class
    also explains, splits the component by a marker watershed seeded with discs of
    ``seed_radius`` pixels at those keypoints. Regions under ``min_area`` pixels join a
    neighbour. Classes without ``explained_keypoints`` (baselines) are never verified, so
    their components stay whole.

    One limit, stated rather than hidden: two objects of the *same* class touching in the
    image are one class to the vote and stay one region.
    """

    def __init__(
        self,
        ratio: float = 0.8,
        min_votes: int = 6,
        min_seeds: int = 6,
        max_candidates: int = 3,
        seed_radius: int = 2,
        min_area: int = 120,
        k: int = 10,
        contrast_threshold: float = 0.03,
        random_state: int = 0,
    ) -> None:
        self.ratio = ratio
        self.min_votes = min_votes
        self.min_seeds = min_seeds
        self.max_candidates = max_candidates
        self.seed_radius = seed_radius
        self.min_area = min_area
        self.k = k
        self.contrast_threshold = contrast_threshold
        self.random_state = random_state

    def _check_params(self) -> None:
        if not 0.0 < self.ratio <= 1.0:
            raise ValueError(f"ratio must be in (0, 1], got {self.ratio!r}")
        for name in ("min_votes", "min_seeds", "max_candidates", "min_area", "k"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise ValueError(f"{name} must be an int >= 1, got {v!r}")
        if int(self.seed_radius) < 0:
            raise ValueError(f"seed_radius must be >= 0 pixels, got {self.seed_radius!r}")

    def fit(self, estimators: Mapping[str, Any]) -> KeypointWatershedSplitter:
        """Pool every class's training descriptors into one nearest-neighbour index."""
        self._check_params()
        pooled = {n: e for n, e in estimators.items() if hasattr(e, "db_desc_")}
        if not pooled:
            raise ValueError(
                "KeypointWatershedSplitter needs fitted estimators with training descriptors "
                f"(db_desc_), got classes {sorted(estimators)} without any"
            )
        self.estimators_ = dict(estimators)
        self.classes_ = sorted(pooled)
        descs = [np.asarray(pooled[n].db_desc_, np.float32) for n in self.classes_]
        owner = np.concatenate([np.full(len(d), i) for i, d in enumerate(descs)])
        self.index_ = DescriptorIndex(
            np.concatenate(descs), owner, len(self.classes_), self.random_state
        )
        return self

    def split(
        self, image: np.ndarray, components: Sequence[np.ndarray], camera: Any = None
    ) -> list[Region]:
        """Regions of every component, in component order (``camera``: the image's
        :class:`~pose.camera.CameraModel`, which the pose models' views need)."""
        if not hasattr(self, "index_"):
            raise RuntimeError("KeypointWatershedSplitter.split before fit(estimators)")
        if camera is None and len(components):
            raise ValueError(
                "KeypointWatershedSplitter.split needs the image's camera model (the pose "
                "models' views are calibrated), got camera=None"
            )
        _check_components(image, components)
        out: list[Region] = []
        with shared_keypoints():  # the models re-read the same crop's SIFT
            for i, comp in enumerate(components):
                out += self._split_one(image, np.asarray(comp, bool), i, camera)
        return out

    def candidates(self, image: np.ndarray, component: np.ndarray) -> list[str]:
        """Classes that at least ``min_votes`` of the component's keypoints vote for, most
        votes first (at most ``max_candidates``)."""
        f = extract_sift(image, component, 0, self.contrast_threshold)
        if len(f) == 0:
            return []
        idx, dist = self.index_.nearest(f.descriptors, self.k)
        valid = idx >= 0
        owner = np.where(valid, self.index_.view_ids[np.maximum(idx, 0)], -1)
        other = valid & (owner != owner[:, :1])  # neighbours of another class than the nearest
        first_other = dist[np.arange(len(idx)), other.argmax(axis=1)]
        second = np.where(other.any(axis=1), first_other, np.inf)
        ok = valid[:, 0] & (dist[:, 0] < self.ratio * second)
        votes = np.bincount(owner[ok, 0], minlength=len(self.classes_))
        order = np.argsort(-votes, kind="stable")[: self.max_candidates]
        return [self.classes_[j] for j in order if votes[j] >= self.min_votes]

    def _split_one(
        self, image: np.ndarray, comp: np.ndarray, index: int, camera: Any
    ) -> list[Region]:
        whole = [Region(comp, index)]
        names = self.candidates(image, comp)
        if len(names) < 2:
            return whole
        from pose.view import View  # the splitter needs it only to ask the models

        view = View(np.asarray(image), camera, comp, None)
        explained: dict[str, np.ndarray] = {}
        for name in names:
            est = self.estimators_[name]
            if hasattr(est, "explained_keypoints"):
                xy = np.round(est.explained_keypoints(view)).astype(int)
                explained[name] = xy
        # A keypoint that several classes explain tells them apart nowhere: dropped.
        keys = {n: {tuple(p) for p in xy} for n, xy in explained.items()}
        seeds, kept, counts = [], [], []
        for name, xy in explained.items():
            others = set().union(*(keys[m] for m in keys if m != name))
            own = np.array([p for p in xy if tuple(p) not in others]).reshape(-1, 2)
            if len(own) < self.min_seeds:
                continue
            seed = np.zeros(comp.shape, np.uint8)
            for x, y in own:
                cv2.circle(seed, (int(x), int(y)), int(self.seed_radius), 1, -1)
            seeds.append(seed.astype(bool) & comp)
            kept.append(name)
            counts.append(len(own))
        if len(seeds) < 2:
            return [Region(comp, index, kept[0], counts[0])] if kept else whole
        labels = _watershed(image, comp, seeds)
        return _regions_from_labels(labels, index, kept, counts, seeds, self.min_area)


class DistanceWatershedSplitter(BaseEstimator):
    """Split components at the necks of their shape, without any model.

    The distance transform of a component peaks once per convex part; the peaks above
    ``peak_fraction`` of the component's maximum, merged where closer than ``min_separation``
    pixels, seed a watershed on the negated distance transform. A component with one peak
    stays whole; regions under ``min_area`` pixels join a neighbour.
    """

    def __init__(
        self, peak_fraction: float = 0.6, min_separation: int = 8, min_area: int = 120
    ) -> None:
        self.peak_fraction = peak_fraction
        self.min_separation = min_separation
        self.min_area = min_area

    def split(
        self, image: np.ndarray, components: Sequence[np.ndarray], camera: Any = None
    ) -> list[Region]:
        if not 0.0 < self.peak_fraction < 1.0:
            raise ValueError(f"peak_fraction must be in (0, 1), got {self.peak_fraction!r}")
        _check_components(image, components)
        out: list[Region] = []
        for i, comp in enumerate(components):
            comp = np.asarray(comp, bool)
            dist = cv2.distanceTransform(comp.astype(np.uint8), cv2.DIST_L2, 5)
            se = np.ones((2 * self.min_separation + 1,) * 2, np.uint8)
            peaks = (dist >= cv2.dilate(dist, se)) & (dist >= self.peak_fraction * dist.max())
            n, plabels = cv2.connectedComponents(peaks.astype(np.uint8), connectivity=8)
            if n - 1 < 2:
                out.append(Region(comp, i))
                continue
            seeds = [plabels == k for k in range(1, n)]
            relief = cv2.normalize(-dist, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
            labels = _watershed(relief, comp, seeds)
            names = [None] * len(seeds)
            out += _regions_from_labels(labels, i, names, [1] * len(seeds), seeds, self.min_area)
        return out


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    union = np.count_nonzero(a | b)
    return 1.0 if union == 0 else np.count_nonzero(a & b) / union


class SplitMemory:
    """A splitter that remembers, within an episode, how each component was split.

    A component whose mask overlaps one split earlier by an intersection over union of at
    least ``min_iou`` is not split again: it keeps that split's seeds (those still inside it)
    and only the watershed runs on its current pixels (a component left whole stays whole).
    Anything else goes to ``splitter``. :meth:`reset` forgets (a new episode, a new table).
    """

    def __init__(self, splitter: Any, min_iou: float = 0.9, min_area: int = 120) -> None:
        if not 0.0 < min_iou <= 1.0:
            raise ValueError(f"min_iou must be in (0, 1], got {min_iou!r}")
        self.splitter, self.min_iou, self.min_area = splitter, float(min_iou), int(min_area)
        self._known: list[tuple[np.ndarray, list[Region]]] = []

    def reset(self) -> None:
        self._known = []

    def split(
        self, image: np.ndarray, components: Sequence[np.ndarray], camera: Any = None
    ) -> list[Region]:
        _check_components(image, components)
        out: list[Region] = []
        known: list[tuple[np.ndarray, list[Region]]] = []
        for i, comp in enumerate(components):
            comp = np.asarray(comp, bool)
            match = next((r for m, r in self._known if _iou(m, comp) >= self.min_iou), None)
            regions = None if match is None else self._again(image, comp, i, match)
            if regions is None:
                regions = [
                    dataclasses.replace(r, component=i)
                    for r in self.splitter.split(image, [comp], camera)
                ]
            known.append((comp, regions))
            out += regions
        self._known = known
        return out

    def _again(
        self, image: np.ndarray, comp: np.ndarray, i: int, before: list[Region]
    ) -> list[Region] | None:
        """``before``'s split of a component redone on ``comp``; None where a seed is gone
        (the arm covers it now: split afresh)."""
        if len(before) == 1:
            r = before[0]
            return [dataclasses.replace(r, mask=comp, component=i)]
        seeds = [r.seed & comp if r.seed is not None else None for r in before]
        if any(s is None or not s.any() for s in seeds):
            return None
        labels = _watershed(image, comp, seeds)
        names = [r.label for r in before]
        counts = [r.n_seeds for r in before]
        return _regions_from_labels(labels, i, names, counts, seeds, self.min_area)
