"""Stages c-d: k-means bunches on hand-made points and their manifold coordinates."""

import numpy as np
import pytest

from pose.manifold import anchor_index, manifold_coordinates
from pose.manifold.bunches import kmeans_locations, make_bunches

CENTRES = np.array([[10.0, 10.0], [60.0, 10.0], [35.0, 50.0]])


def _points(seed=0, n=20):
    rng = np.random.default_rng(seed)
    return np.vstack([c + rng.normal(0, 1.5, (n, 2)) for c in CENTRES])


def test_kmeans_finds_the_hand_made_groups():
    xy = _points()
    labels, centres = kmeans_locations(xy, 3, seed=0)
    truth = np.repeat(np.arange(3), 20)
    for j in range(3):  # each true group is exactly one cluster
        assert len(np.unique(labels[truth == j])) == 1
    found = np.sort(centres[:, 0])
    np.testing.assert_allclose(found, np.sort(CENTRES[:, 0]), atol=1.5)


def test_kmeans_is_seeded_and_checks_its_input():
    xy = np.random.default_rng(4).uniform(0, 100, (80, 2))
    a, _ = kmeans_locations(xy, 5, seed=7)
    b, _ = kmeans_locations(xy, 5, seed=7)
    np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="at least n_bunches=5 keypoints, got 3"):
        kmeans_locations(xy[:3], 5)


def test_bunch_vectors_join_appearance_and_normalised_geometry():
    xy = np.array([[0.0, 0.0], [2.0, 0.0], [100.0, 0.0], [102.0, 0.0]])
    desc = np.zeros((4, 128))
    desc[:2, 0] = 1.0
    desc[2:, 1] = 1.0
    b = make_bunches(xy, desc, centre=np.array([51.0, 0.0]), size=50.0, n_bunches=2,
                     geometry_weight=2.0)  # fmt: skip
    left = int(np.argmin(b.offsets[:, 0]))
    np.testing.assert_allclose(b.offsets[left], [-1.0, 0.0])
    np.testing.assert_allclose(b.vectors[left, :128], np.eye(128)[0])
    np.testing.assert_allclose(b.vectors[left, 128:], [-2.0, 0.0, 2.0 * 1.0 / 50.0])
    assert b.counts.tolist() == [2, 2]


def test_manifold_is_invariant_to_cluster_numbering_and_picks_the_reference_anchor():
    xy = _points()
    desc = np.random.default_rng(5).random((len(xy), 128))
    desc /= np.linalg.norm(desc, axis=1, keepdims=True)
    centre = xy.mean(axis=0)
    b = make_bunches(xy, desc, centre, 40.0, 3, seed=0)
    # reference pointing right: the anchor is the bunch around (60, 10)
    a = anchor_index(b, 0.0)
    assert np.linalg.norm(b.offsets[a] * 40.0 + centre - CENTRES[1]) < 2.0
    perm = np.array([2, 0, 1])
    shuffled = type(b)(b.vectors[perm], b.offsets[perm], b.counts[perm], b.labels)
    np.testing.assert_allclose(manifold_coordinates(b, 0.0), manifold_coordinates(shuffled, 0.0))
    assert manifold_coordinates(b, 0.0).shape == (3,)
