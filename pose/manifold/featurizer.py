"""Stage e: the manifold vector of a view, built from named feature blocks.

* ``"bunches"``: the bunch distances (:mod:`pose.manifold.coordinates`) - to the anchor bunch
  along the reference direction (``anchor="reference"``), or all pairwise (``anchor=None``);
* ``"shape"``: the 73-D silhouette descriptor shared with shape recognition, the silhouette's
  elongation and its angular size ``log(size / focal)``. The descriptor is invariant to affine
  maps and scale, so it cannot tell a 60x45 face of a box from a 70x45 one; the last two can;
* ``"words"``: a bag-of-visual-words histogram of the inliers (:mod:`pose.vocabulary`), which
  tells apart faces of equal shape.

The blocks are standardised, then weighted so that each counts ``<block>_weight`` times as much
as the first block in the regressor's Euclidean distances, whatever its dimension. A silhouette
block that cannot be computed (no mask) is NaN and replaced by the training mean (neutral).
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np
from sklearn.base import BaseEstimator
from sklearn.utils.validation import check_is_fitted

from pose.manifold.bunches import Bunches
from pose.manifold.coordinates import manifold_coordinates, pairwise_coordinates
from pose.orientation import elongation
from pose.shape.descriptors import shape_descriptor
from pose.vocabulary import learn_vocabulary, word_histogram

BLOCKS = ("bunches", "shape", "words")
ANCHORS = ("reference", None)
N_SHAPE = 73 + 2  # shared descriptor + elongation + log angular size
SHAPE_SIDE = 48


def shape_features(mask: np.ndarray | None) -> np.ndarray | None:
    """The shared 73-D silhouette descriptor, or None without a usable mask.

    The silhouette is cropped and resampled to at most ``SHAPE_SIDE`` pixels a side first: the
    descriptor is scale-invariant, and its cost grows with the pixel count (about 30 ms for a
    100x100 silhouette, 3.5 ms at 48x48), which would otherwise eat the whole time budget.
    """
    if mask is None:
        return None
    m = np.asarray(mask, np.uint8)
    x, y, w, h = cv2.boundingRect(m)
    crop = m[y : y + h, x : x + w].astype(np.float32)
    if np.count_nonzero(crop) < 16:
        return None
    scale = SHAPE_SIDE / max(crop.shape)
    if scale < 1.0:
        size = (max(1, round(crop.shape[1] * scale)), max(1, round(crop.shape[0] * scale)))
        crop = cv2.resize(crop, size, interpolation=cv2.INTER_AREA)
    crop = np.pad(crop >= 0.5, 2)
    if np.count_nonzero(crop) < 16:
        return None
    return np.asarray(shape_descriptor(crop), float).ravel()


class ManifoldFeaturizer(BaseEstimator):
    """Named feature blocks -> one standardised, block-weighted vector per view.

    ``fit`` learns the visual words (from the training descriptors) and the standardisation;
    ``row`` computes the blocks that need no learning for one view, ``transform`` adds the words
    block and scales. ``block_slices_`` names the columns of each block after ``fit``.
    """

    def __init__(
        self,
        blocks: Sequence[str] = BLOCKS,
        anchor: str | None = "reference",
        n_words: int = 32,
        shape_weight: float = 1.0,
        words_weight: float = 3.0,
    ):
        self.blocks = blocks
        self.anchor = anchor
        self.n_words = n_words
        self.shape_weight = shape_weight
        self.words_weight = words_weight

    def validate(self) -> None:
        blocks = tuple(self.blocks)
        if not blocks or len(set(blocks)) != len(blocks) or not set(blocks) <= set(BLOCKS):
            raise ValueError(f"blocks must be distinct names from {BLOCKS}, got {self.blocks!r}")
        if self.anchor not in ANCHORS:
            raise ValueError(f"anchor must be 'reference' or None, got {self.anchor!r}")
        if "words" in blocks and self.n_words < 1:
            raise ValueError(f"n_words must be >= 1 with a 'words' block, got {self.n_words}")

    @property
    def uses_bunches(self) -> bool:
        return "bunches" in self.blocks

    def n_columns(self, n_bunches: int) -> int:
        """Width of the feature vector for views cut into ``n_bunches`` bunches."""
        widths = {
            "bunches": n_bunches
            if self.anchor == "reference"
            else n_bunches * (n_bunches - 1) // 2,
            "shape": N_SHAPE,
            "words": self.n_words,
        }
        return sum(widths[b] for b in self.blocks)

    def row(
        self,
        bunches: Bunches | None,
        angle: float,
        mask: np.ndarray | None,
        region: np.ndarray,
        size: float,
        focal: float,
    ) -> np.ndarray:
        """The ``"bunches"`` and ``"shape"`` blocks of one view (in ``blocks`` order)."""
        parts = []
        for name in self.blocks:
            if name == "bunches":
                if self.anchor == "reference":
                    parts.append(manifold_coordinates(bunches, angle))
                else:
                    parts.append(pairwise_coordinates(bunches))
            elif name == "shape":
                shape = shape_features(mask)
                if shape is None:
                    shape = np.full(N_SHAPE - 2, np.nan)
                parts.append(np.r_[shape, elongation(region), np.log(size / focal)])
        return np.concatenate(parts) if parts else np.zeros(0)

    def _words(self, descriptors: np.ndarray) -> np.ndarray:
        return word_histogram(descriptors, self.words_)

    def _assemble(self, rows: np.ndarray, descriptor_sets: Sequence[np.ndarray]) -> np.ndarray:
        if "words" not in self.blocks:
            return rows
        # row() leaves the words out; they go at their place in the block order
        W = np.array([self._words(d) for d in descriptor_sets]).reshape(len(rows), -1)
        i = self.blocks.index("words")
        before = sum(self._width[b] for b in self.blocks[:i])
        return np.c_[rows[:, :before], W, rows[:, before:]]

    def fit(
        self,
        rows: Sequence[np.ndarray],
        descriptor_sets: Sequence[np.ndarray],
        vocabulary_descriptors: np.ndarray,
        seed: int = 0,
    ) -> ManifoldFeaturizer:
        """Learn the words from ``vocabulary_descriptors`` and the standardisation from the
        training ``rows`` (from :meth:`row`) with each row's descriptors."""
        self.validate()
        rows = np.array(rows, dtype=float).reshape(len(rows), -1)
        if "words" in self.blocks:
            self.words_ = learn_vocabulary(vocabulary_descriptors, self.n_words, seed)
        else:
            self.words_ = np.zeros((0, 128), np.float32)
        self._set_widths(rows.shape[1])
        X = self._assemble(rows, descriptor_sets)
        known = np.isfinite(X).any(axis=0)  # silhouette columns are NaN when no view has a mask
        self.x_mean_ = np.zeros(X.shape[1])
        self.x_mean_[known] = np.nanmean(X[:, known], axis=0)
        sd = np.ones(X.shape[1])
        sd[known] = np.nanstd(X[:, known], axis=0)
        self.x_scale_ = np.where(sd > 1e-12, sd, 1.0)
        return self

    def _set_widths(self, n_row_columns: int) -> None:
        """Block widths from the learnt sizes; the bunches block takes what the others leave."""
        fixed = {"shape": N_SHAPE, "words": len(self.words_)}
        self._width = {b: fixed.get(b, 0) for b in self.blocks}
        if "bunches" in self.blocks:
            self._width["bunches"] = n_row_columns - (N_SHAPE if "shape" in self.blocks else 0)
        start, self.block_slices_ = 0, {}
        for b in self.blocks:
            self.block_slices_[b] = slice(start, start + self._width[b])
            start += self._width[b]

    def restore(self, words: np.ndarray, x_mean: np.ndarray, x_scale: np.ndarray):
        """Set the fitted state from saved arrays (checked for consistency by the caller)."""
        self.words_ = np.asarray(words, np.float32)
        self.x_mean_ = np.asarray(x_mean, float)
        self.x_scale_ = np.asarray(x_scale, float)
        self._set_widths(len(self.x_mean_) - len(self.words_))
        if any(w < 0 for w in self._width.values()) or (
            "bunches" in self.blocks and self._width["bunches"] < 1
        ):
            raise ValueError(
                f"{len(self.x_mean_)} feature columns cannot hold the blocks {self.blocks}"
            )
        return self

    def transform(self, rows: np.ndarray, descriptor_sets: Sequence[np.ndarray]) -> np.ndarray:
        """Standardised, block-weighted feature matrix of the views."""
        check_is_fitted(self, "x_mean_")
        X = self._assemble(np.atleast_2d(np.asarray(rows, float)), descriptor_sets)
        X = np.where(np.isnan(X), self.x_mean_, X)
        Z = (X - self.x_mean_) / self.x_scale_
        ref = self._width[self.blocks[0]]
        for b, w in (("shape", self.shape_weight), ("words", self.words_weight)):
            if b in self.blocks and b != self.blocks[0]:
                Z[:, self.block_slices_[b]] *= w * np.sqrt(ref / self._width[b])
        return Z
