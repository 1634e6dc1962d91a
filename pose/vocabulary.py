"""Appearance block of the manifold vector: a bag-of-words histogram of the inlier descriptors.

The bunch distances say how the object's parts differ from one another, not which parts are in
view, and the silhouette block cannot tell apart faces of equal shape (the six faces of a cube).
Which resting face is up is written in the texture: a histogram of the keypoints over a small
vocabulary of visual words, learnt by k-means on the training descriptors, says so with a
fixed-length vector (Sivic and Zisserman, 2003). It is normalised by the keypoint count, so it
describes the visible texture whatever the object's size, and the square root (Hellinger
mapping) keeps a few frequent words from dominating the Euclidean distances of the RBF.
"""

from __future__ import annotations

import cv2
import numpy as np

MAX_TRAIN_DESCRIPTORS = 8000


def learn_vocabulary(descriptors: np.ndarray, n_words: int, seed: int = 0) -> np.ndarray:
    """``(n_words, 128)`` unit word vectors: seeded k-means++ on (a sample of) the descriptors."""
    d = np.asarray(descriptors, np.float32)
    if len(d) < n_words:
        raise ValueError(f"need at least n_words={n_words} descriptors, got {len(d)}")
    rng = np.random.default_rng(seed)
    if len(d) > MAX_TRAIN_DESCRIPTORS:
        d = d[np.sort(rng.choice(len(d), MAX_TRAIN_DESCRIPTORS, replace=False))]
    cv2.setRNGSeed(int(seed))
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 1e-4)
    _, _, words = cv2.kmeans(d, n_words, None, crit, 1, cv2.KMEANS_PP_CENTERS)
    return (words / np.maximum(np.linalg.norm(words, axis=1, keepdims=True), 1e-12)).astype(
        np.float32
    )


def word_histogram(descriptors: np.ndarray, words: np.ndarray) -> np.ndarray:
    """``(n_words,)`` square-rooted share of the unit ``descriptors`` nearest to each word."""
    hist = np.zeros(len(words))
    if len(descriptors):
        nearest = np.argmax(np.asarray(descriptors, np.float32) @ words.T, axis=1)
        hist = np.bincount(nearest, minlength=len(words)) / len(descriptors)
    return np.sqrt(hist)
