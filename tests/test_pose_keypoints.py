"""Stage a: SIFT keypoints restricted to the mask, unit descriptors."""

import numpy as np
import pytest

from pose.features.keypoints import extract_sift
from pose.synthetic import card_texture


@pytest.fixture(scope="module")
def scene():
    img = np.full((240, 320, 3), 90, np.uint8)
    img[20:220, 60:260] = card_texture(seed=3)
    mask = np.zeros((240, 320), bool)
    mask[20:220, 60:160] = True  # only the left half of the card
    return img, mask


def test_descriptors_are_unit_length(scene):
    img, _ = scene
    f = extract_sift(img)
    assert len(f) > 50
    assert f.descriptors.shape == (len(f), 128)
    np.testing.assert_allclose(np.linalg.norm(f.descriptors, axis=1), 1.0, atol=1e-5)


def test_keypoints_stay_inside_the_mask(scene):
    img, mask = scene
    f = extract_sift(img, mask, mask_dilation=2)
    assert len(f) > 20
    u, v = f.xy[:, 0], f.xy[:, 1]
    assert np.all((u >= 60 - 3) & (u <= 160 + 2) & (v >= 20 - 3) & (v <= 220 + 2))
    full = extract_sift(img)
    assert len(f) < len(full)


def test_crop_gives_the_same_keypoints_as_the_full_image(scene):
    """The mask's bounding-box crop is an optimisation: locations must come back in image
    coordinates, matching those found on the whole image inside the mask."""
    img, mask = scene
    cropped = extract_sift(img, mask)
    full = extract_sift(img)
    inside = full.xy[mask[np.clip(full.xy[:, 1].round().astype(int), 0, 239),
                          np.clip(full.xy[:, 0].round().astype(int), 0, 319)]]  # fmt: skip
    d = np.linalg.norm(cropped.xy[:, None] - inside[None], axis=2).min(axis=1)
    assert np.mean(d < 1.0) > 0.8


@pytest.mark.parametrize("case", ["blank", "empty_mask"])
def test_no_keypoints_gives_empty_features(case, scene):
    img, mask = scene
    if case == "blank":
        f = extract_sift(np.full((240, 320, 3), 128, np.uint8))
    else:
        f = extract_sift(img, np.zeros_like(mask))
    assert len(f) == 0 and f.descriptors.shape == (0, 128)


def test_upscaled_crop_finds_more_keypoints_on_a_small_object_in_image_pixels(scene):
    """``upscale`` enlarges the crop before SIFT: a card 80 px wide gets several times more
    keypoints, still inside its mask, and on a large card the keypoints found both ways sit at
    the same image locations (the mapping back keeps pixel centres)."""
    import cv2

    img, _ = scene
    card = np.zeros((240, 320), bool)
    card[20:220, 60:260] = True
    plain, big = extract_sift(img, card), extract_sift(img, card, upscale=2)
    d = np.linalg.norm(plain.xy[:, None] - big.xy[None], axis=2).min(axis=1)
    assert np.median(d) < 0.3 and np.mean(d < 0.5) > 0.6

    small = np.full((240, 320, 3), 90, np.uint8)
    small[100:160, 120:200] = cv2.resize(img[20:220, 60:260], (80, 60), cv2.INTER_AREA)
    mask = np.zeros((240, 320), bool)
    mask[100:160, 120:200] = True
    n1 = len(extract_sift(small, mask))
    f3 = extract_sift(small, mask, upscale=3)
    assert len(f3) > 3 * n1
    u, v = f3.xy[:, 0], f3.xy[:, 1]
    assert np.all((u >= 120 - 3) & (u <= 200 + 2) & (v >= 100 - 3) & (v <= 160 + 2))


def test_upscale_below_one_is_refused_with_the_valid_range(scene):
    from pose.features.keypoints import SiftKeypoints

    img, mask = scene
    with pytest.raises(ValueError, match="upscale must be >= 1"):
        extract_sift(img, mask, upscale=0.5)
    with pytest.raises(ValueError, match="upscale must be >= 1"):
        SiftKeypoints(upscale=float("nan")).validate()


def test_shared_block_detects_each_image_and_setting_once(scene, monkeypatch):
    from pose.features import keypoints as kp

    img, mask = scene
    calls = []
    detect = kp._detect_sift
    monkeypatch.setattr(kp, "_detect_sift", lambda *a: calls.append(a[2:]) or detect(*a))
    with kp.shared_keypoints():
        first = extract_sift(img, mask, 0, 0.03)
        with kp.shared_keypoints():  # a nested block shares the outer one's features
            assert extract_sift(img.copy(), mask.copy(), 0, 0.03) is first
        assert extract_sift(img, mask, 50, 0.03) is not first  # other settings: detected
        assert extract_sift(img, None, 0, 0.03) is not first  # other mask: detected
        assert not first.descriptors.flags.writeable  # shared: nobody may change them
        with pytest.raises(ValueError, match="read-only"):
            first.xy += 1
    assert len(calls) == 3
    outside = extract_sift(img, mask, 0, 0.03)  # after the block: detected afresh, same answer
    assert outside is not first and len(calls) == 4 and outside.descriptors.flags.writeable
    for a, b in zip((first.xy, first.descriptors, first.angles),
                    (outside.xy, outside.descriptors, outside.angles), strict=True):  # fmt: skip
        assert np.array_equal(a, b)
