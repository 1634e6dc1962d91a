"""Stage d: manifold coordinates of a view from its bunches (eq. 2).

The coordinates are the squared distances ``||e_i - e*||^2`` of the bunch vectors to an anchor
bunch ``e*``. k-means numbers its clusters arbitrarily, so an order has to be imposed:

* the anchor is the bunch lying furthest along the object's in-plane reference direction
  (by default the keypoint-voted heading, :func:`pose.orientation.keypoint_heading`; else the
  silhouette's, :func:`pose.orientation.reference_angle`), i.e. with the largest projection of
  its centroid offset on that direction. The reference turns with the object, so the anchor is
  the same physical part of the object from one view to the next (the most populated bunch
  was tried first: its direction jumps by up to 180 degrees between neighbouring views);
* the other distances are sorted in increasing order. A sorted vector is invariant to the
  arbitrary cluster numbering and changes continuously when bunches move, so nearby poses get
  nearby coordinates - what a regressor on the manifold needs.

Distances between bunch vectors do not change when the image is shifted, scaled or rotated in
plane, so the coordinates describe the object's *aspect*. The in-plane angle is carried
separately by the reference direction; the regressor predicts the rotation relative to it. One
extra coordinate, the anchor's projection on the reference direction, completes the ``n_bunches``
values.
"""

from __future__ import annotations

import numpy as np

from pose.manifold.bunches import Bunches


def anchor_index(b: Bunches, reference_angle: float) -> int:
    """The bunch whose centroid reaches furthest along the reference direction."""
    direction = np.array([np.cos(reference_angle), np.sin(reference_angle)])
    return int(np.argmax(b.offsets @ direction))


def manifold_coordinates(b: Bunches, reference_angle: float) -> np.ndarray:
    """``(n_bunches,)`` coordinates: sorted ``||e_i - e*||^2`` of the non-anchor bunches, then
    the anchor's projection on the reference direction."""
    a = anchor_index(b, reference_angle)
    d2 = ((b.vectors - b.vectors[a]) ** 2).sum(axis=1)
    direction = np.array([np.cos(reference_angle), np.sin(reference_angle)])
    return np.r_[np.sort(np.delete(d2, a)), float(b.offsets[a] @ direction)]


def pairwise_coordinates(b: Bunches) -> np.ndarray:
    """``(k (k - 1) / 2,)`` sorted squared distances between all pairs of bunch vectors.

    The anchor-free alternative (the ``manifold-no-anchor`` ablation): sorting makes it
    independent of the cluster numbering too, but it forgets which distances belong to the same
    bunch, and it carries nothing about the reference direction.
    """
    k = len(b.vectors)
    d2 = ((b.vectors[:, None] - b.vectors[None]) ** 2).sum(axis=2)
    return np.sort(d2[np.triu_indices(k, 1)])
