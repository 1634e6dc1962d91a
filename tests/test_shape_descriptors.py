"""Invariances and discrimination of the Fourier, ART and affine-moment shape descriptors."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from pose.shape.descriptors import (
    AMI_SLICE,
    ART_SLICE,
    DESCRIPTOR_LENGTH,
    FOURIER_SLICE,
    affine_moment_invariants,
    art_descriptor,
    fourier_descriptor,
    shape_descriptor,
    shape_descriptors,
)
from pose.shape.silhouettes import SHAPES, synthetic_silhouette

SIZE = 128
BLOCKS = {"fourier": FOURIER_SLICE, "art": ART_SLICE, "ami": AMI_SLICE}
# L2 tolerances on each block under rotation / scale / translation of a 128 px silhouette
# (scaled down to 60 %). ART is the most resolution-sensitive (its disk radius is set by the
# farthest pixel); the AMI block's fifth root of I4 amplifies discretisation noise near zero.
TOLERANCE = {"fourier": 0.05, "art": 0.10, "ami": 0.035}
SIMILARITIES = [
    {"angle_deg": 33.0},
    {"angle_deg": 71.0, "scale": 0.7},
    {"scale": 0.6},
    {"offset": (9.0, -6.0)},
    {"angle_deg": -120.0, "scale": 0.8, "offset": (5.0, 3.0)},
]


@pytest.fixture(scope="module")
def reference() -> dict[str, np.ndarray]:
    return {kind: shape_descriptor(synthetic_silhouette(kind, SIZE)) for kind in SHAPES}


def test_layout_and_dtype(reference):
    d = reference["star"]
    assert d.shape == (DESCRIPTOR_LENGTH,) == (73,)
    assert d.dtype == np.float64
    assert np.all(np.isfinite(d))
    mask = synthetic_silhouette("star", SIZE)
    np.testing.assert_array_equal(d[FOURIER_SLICE], fourier_descriptor(mask))
    np.testing.assert_array_equal(d[ART_SLICE], art_descriptor(mask))
    np.testing.assert_array_equal(d[AMI_SLICE], affine_moment_invariants(mask))
    assert shape_descriptors([mask, mask]).shape == (2, 73)


@pytest.mark.parametrize("kind", list(SHAPES))
@pytest.mark.parametrize("transform", SIMILARITIES, ids=lambda t: ",".join(map(str, t.items())))
def test_similarity_invariance(reference, kind, transform):
    moved = shape_descriptor(synthetic_silhouette(kind, SIZE, **transform))
    for block, sl in BLOCKS.items():
        change = np.linalg.norm(moved[sl] - reference[kind][sl])
        assert change < TOLERANCE[block], f"{block} changed by {change:.4f} under {transform}"


@pytest.mark.parametrize("kind", list(SHAPES))
@pytest.mark.parametrize("shear", [0.3, -0.5])
def test_affine_moment_invariants_survive_shear(reference, kind, shear):
    sheared = affine_moment_invariants(synthetic_silhouette(kind, SIZE, shear=shear, angle_deg=20))
    change = np.linalg.norm(sheared - reference[kind][AMI_SLICE])
    assert change < TOLERANCE["ami"]


def test_shear_changes_contour_descriptors_but_not_moment_invariants(reference):
    """Shear is not a similarity: Fourier/ART must notice it, the AMIs must not."""
    sheared = shape_descriptor(synthetic_silhouette("triangle", SIZE, shear=0.5))
    ref = reference["triangle"]
    assert np.linalg.norm(sheared[FOURIER_SLICE] - ref[FOURIER_SLICE]) > 2 * TOLERANCE["fourier"]
    assert np.linalg.norm(sheared[AMI_SLICE] - ref[AMI_SLICE]) < 0.002


@pytest.mark.parametrize("block", ["fourier", "art"])
def test_different_shapes_stay_apart(reference, block):
    sl = BLOCKS[block]
    for a, b in itertools.combinations(SHAPES, 2):
        gap = np.linalg.norm(reference[a][sl] - reference[b][sl])
        assert gap > 1.5 * TOLERANCE[block], f"{a} vs {b}: {block} gap {gap:.4f}"


def test_moment_invariants_separate_affinely_distinct_shapes(reference):
    """Triangle, L and ellipse are not affine images of each other; AMIs tell them apart."""
    for a, b in [("triangle", "ellipse"), ("ell", "ellipse"), ("triangle", "star")]:
        gap = np.linalg.norm(reference[a][AMI_SLICE] - reference[b][AMI_SLICE])
        assert gap > 2 * TOLERANCE["ami"], f"{a} vs {b}: gap {gap:.4f}"


def test_ellipse_and_rectangle_are_affine_images_of_circle_and_square():
    """Known closed forms: I1 = 1/(16 pi^2) for any ellipse, 1/144 for any parallelogram."""
    ami_e = affine_moment_invariants(synthetic_silhouette("ellipse", 256, angle_deg=10))
    ami_r = affine_moment_invariants(synthetic_silhouette("rectangle", 256, shear=0.4))
    assert ami_e[0] == pytest.approx(np.sqrt(1 / (16 * np.pi**2)), rel=2e-3)
    assert ami_r[0] == pytest.approx(np.sqrt(1 / 144), rel=2e-3)


def test_border_touching_and_multi_part_masks_work():
    mask = np.zeros((40, 40), bool)
    mask[:, :12] = True  # touches three borders
    mask[30:35, 30:35] = True  # a second, smaller part
    d = shape_descriptor(mask)
    assert np.all(np.isfinite(d))


@pytest.mark.parametrize(
    ("mask", "message"),
    [
        (np.zeros((32, 32), bool), "at least 9 foreground"),
        (np.ones((4, 4, 3), bool), "2-D mask"),
        (np.full((8, 8), np.nan), "NaN"),
        (np.array([["a"]]), "bool or numeric"),
    ],
)
def test_bad_masks_give_clear_errors(mask, message):
    with pytest.raises(ValueError, match=message):
        shape_descriptor(mask)
