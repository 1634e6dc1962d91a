"""MPEG-7 CE-Shape-1 and ETH-80 loaders on small images written in each layout."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from pose.shape.datasets import detect_layout, load_dataset, load_eth80, load_mpeg7, read_silhouette
from pose.shape.silhouettes import synthetic_silhouette


def _save(mask: np.ndarray, path: Path, grey_background: bool = False) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    img = (mask * 255).astype(np.uint8)
    if grey_background:  # a photo-like map: noise-free but not two-level
        img = np.where(mask, 200, 30).astype(np.uint8)
        img[0, 0] = 90
    Image.fromarray(img).save(path)


def write_mpeg7(root: Path) -> None:
    for cls, kind in [("apple", "ellipse"), ("Bone", "cross"), ("HCircle", "star")]:
        for i in (1, 2, 3):
            _save(synthetic_silhouette(kind, 48, angle_deg=30 * i), root / f"{cls}-{i}.gif")


def write_eth80(root: Path, cropped: bool = False) -> None:
    for category, kind in [("cup", "ellipse"), ("pear", "triangle")]:
        for inst in (1, 2):
            folder = root / category / (f"{inst}" if cropped else f"{category}{inst}")
            if not cropped:
                folder = folder / "maps"
            for a in (0, 90):
                name = f"{category}{inst}-{a:03d}-000{'' if cropped else '-map'}.png"
                _save(synthetic_silhouette(kind, 40, angle_deg=a + inst), folder / name, cropped)


def test_mpeg7_layout_loads_gifs(tmp_path):
    write_mpeg7(tmp_path)
    (tmp_path / "README.txt").write_text("not an image")  # ignored
    data = load_mpeg7(tmp_path)
    assert len(data) == 9
    assert data.classes == ["Bone", "HCircle", "apple"]
    assert sorted(set(data.labels)) == data.classes
    assert len(set(data.groups)) == 9
    mask = data.masks[list(data.labels).index("apple")]
    assert mask.dtype == bool and mask.shape == (48, 48)
    np.testing.assert_array_equal(mask, synthetic_silhouette("ellipse", 48, angle_deg=30))
    assert detect_layout(tmp_path) == "mpeg7"


@pytest.mark.parametrize("cropped", [False, True])
def test_eth80_layouts_load_with_instance_groups(tmp_path, cropped):
    write_eth80(tmp_path, cropped=cropped)
    data = load_dataset(tmp_path)  # auto-detected
    assert detect_layout(tmp_path) == "eth80"
    assert len(data) == 8
    assert data.classes == ["cup", "pear"]
    assert set(data.groups) == (
        {"cup/1", "cup/2", "pear/1", "pear/2"}
        if cropped
        else {"cup/cup1", "cup/cup2", "pear/pear1", "pear/pear2"}
    )
    # the grey-background variant is binarised by Otsu to the same silhouette
    first = data.masks[0]
    np.testing.assert_array_equal(first, synthetic_silhouette("ellipse", 40, angle_deg=1))


def test_large_images_are_downscaled(tmp_path):
    _save(synthetic_silhouette("star", 400), tmp_path / "star-1.png")
    assert read_silhouette(tmp_path / "star-1.png", max_side=100).shape == (100, 100)
    assert read_silhouette(tmp_path / "star-1.png", max_side=None).shape == (400, 400)


def test_unreadable_image_is_named(tmp_path):
    write_mpeg7(tmp_path)
    bad = tmp_path / "apple-4.gif"
    bad.write_bytes(b"GIF89a but not really")
    with pytest.raises(ValueError, match="apple-4.gif"):
        load_mpeg7(tmp_path)


def test_empty_image_is_named(tmp_path):
    write_eth80(tmp_path)
    empty = tmp_path / "cup" / "cup1" / "maps" / "cup1-180-000-map.png"
    _save(np.zeros((40, 40), bool), empty)
    with pytest.raises(ValueError, match="cup1-180-000-map.png.*empty silhouette"):
        load_eth80(tmp_path)


def test_layout_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="does not exist"):
        load_dataset(tmp_path / "missing")
    with pytest.raises(ValueError, match="cannot tell the layout"):
        detect_layout(tmp_path)
    with pytest.raises(ValueError, match="unknown layout 'coil'"):
        load_dataset(tmp_path, layout="coil")
    with pytest.raises(ValueError, match="no MPEG-7 files"):
        load_mpeg7(tmp_path)


@pytest.mark.slow
def test_shapes_eval_cli_on_mpeg7_and_eth80_folders(tmp_path, capsys):
    import json

    from scorbot_gym.cli import main

    mpeg = tmp_path / "mpeg7"
    for cls in ("ellipse", "star", "triangle", "cross"):
        for i in range(8):
            mask = synthetic_silhouette(cls, 64, angle_deg=45 * i, scale=0.7 + 0.04 * i)
            _save(mask, mpeg / f"{cls}-{i + 1}.gif")
    out = tmp_path / "out" / "mpeg7.json"
    argv = ["shapes", "eval", "--data", str(mpeg), "--json", str(out), "--png",
            str(tmp_path / "out" / "cm.png"), "--seed", "1"]  # fmt: skip
    assert main(argv) == 0
    result = json.loads(out.read_text())
    assert result["layout"] == "mpeg7" and result["split"] == "stratified random"
    assert result["n_test"] == 16 and result["classes"] == ["cross", "ellipse", "star", "triangle"]
    assert result["classifiers"]["flr"]["accuracy"] >= 0.9
    for r in result["classifiers"].values():  # tuned: main parameter and ART block weight
        assert len(r["best_params"]) == 2 and r["best_params"]["art_weight"] in (1.0, 2.0, 3.0)
    assert (tmp_path / "out" / "cm.png").stat().st_size > 1000

    eth = tmp_path / "eth"
    write_eth80(eth)
    out = tmp_path / "eth.json"
    assert main(["shapes", "eval", "--data", str(eth), "--layout", "eth80", "--no-tune",
                 "--json", str(out)]) == 0  # fmt: skip
    result = json.loads(out.read_text())
    assert result["split"] == "grouped" and result["n_test"] == 4  # one instance per category


def test_shapes_eval_cli_reports_bad_arguments(tmp_path, capsys):
    from scorbot_gym.cli import main

    assert main(["shapes", "eval", "--data", str(tmp_path / "nope")]) == 2
    assert "does not exist" in capsys.readouterr().err
    write_mpeg7(tmp_path)
    assert main(["shapes", "eval", "--data", str(tmp_path), "--with-size"]) == 2
    assert "rendered silhouettes" in capsys.readouterr().err
