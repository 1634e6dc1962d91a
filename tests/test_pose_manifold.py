"""Stage d on real SIFT features: the manifold vector ignores where the object is in the image."""

import numpy as np
import pytest

from pose.features.keypoints import extract_sift
from pose.manifold import KMeansBunches, ManifoldFeaturizer, SilhouetteDirection
from pose.synthetic import card_texture

CONTRAST = 0.03


def _manifold_input(img, xy, desc, centre, size, mask):
    """Bunch + silhouette blocks of one view, with the silhouette reference direction."""
    angle = SilhouetteDirection().training_angle(img, mask, centre, None)
    b = KMeansBunches(n_bunches=6).build(xy, desc, centre, size, seed=0)
    x = ManifoldFeaturizer(blocks=("bunches", "shape")).row(b, angle, mask, mask, size, 1.0)
    return x, angle


def _scene(dx, dy):
    img = np.full((240, 320, 3), 90, np.uint8)
    mask = np.zeros((240, 320), bool)
    tex = card_texture(seed=7, size=120)
    img[40 + dy : 160 + dy, 60 + dx : 180 + dx] = tex
    mask[40 + dy : 160 + dy, 60 + dx : 180 + dx] = True
    return img, mask


@pytest.mark.parametrize("shift", [(0, 0), (37, 21), (100, -10), (-30, 50)])
def test_manifold_vector_does_not_change_when_the_object_shifts(shift):
    """Shifts keep the card (and the SIFT crop around it) inside the image."""

    def coords(dx, dy):
        img, mask = _scene(dx, dy)
        f = extract_sift(img, mask, 0, CONTRAST)
        c = np.array([119.5 + dx, 99.5 + dy])  # the card's centre
        return _manifold_input(img, f.xy, f.descriptors, c, 120.0, mask)

    (x0, a0), (x1, a1) = coords(0, 0), coords(*shift)
    assert x0.shape == (6 + 73 + 2,)
    np.testing.assert_allclose(x1, x0, atol=1e-9)
    assert a1 == pytest.approx(a0, abs=1e-9)


def test_manifold_vector_changes_with_the_object():
    img, mask = _scene(0, 0)
    f = extract_sift(img, mask, 0, CONTRAST)
    x0, _ = _manifold_input(img, f.xy, f.descriptors, np.array([119.5, 99.5]), 120.0, mask)
    other = img.copy()
    other[40:160, 60:180] = np.rot90(other[40:160, 60:180])  # turned by 90 degrees in plane
    g = extract_sift(other, mask, 0, CONTRAST)
    x1, _ = _manifold_input(other, g.xy, g.descriptors, np.array([119.5, 99.5]), 120.0, mask)
    # turned in plane: the aspect coordinates stay close, the silhouette (a square) is the same
    assert np.linalg.norm(x1[:6] - x0[:6]) < 0.5 * np.linalg.norm(x0[:6])
    tex2 = _scene(0, 0)[0]
    tex2[40:160, 60:180] = card_texture(seed=8, size=120)  # a different object entirely
    h = extract_sift(tex2, mask, 0, CONTRAST)
    x2, _ = _manifold_input(tex2, h.xy, h.descriptors, np.array([119.5, 99.5]), 120.0, mask)
    assert not np.allclose(x2[:6], x0[:6], atol=1e-3)
