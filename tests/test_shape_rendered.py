"""Catalogue silhouettes rendered by the simulator, the on-disk cache, and ``shapes eval``."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pose.shape.descriptors import shape_descriptors
from pose.shape.flr import FLRClassifier
from scorbot_gym.cli import main
from scorbot_gym.data.shapes import render_catalogue_silhouettes, viewpoint_cameras

OBJECTS = ("box", "tennis_ball", "large_marker")
PER_OBJECT = 8


@pytest.fixture(scope="session")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("scorbot_gym_cache")


@pytest.fixture(scope="session")
def rendered(cache):
    mp = pytest.MonkeyPatch()  # session-scoped environment for the cache location
    mp.setenv("SCORBOT_GYM_CACHE", str(cache))
    yield render_catalogue_silhouettes(OBJECTS, n_per_object=PER_OBJECT, seed=11)
    mp.undo()


def test_rendered_silhouettes_are_usable(rendered):
    assert len(rendered) == len(OBJECTS) * PER_OBJECT
    assert sorted(set(rendered.labels)) == sorted(OBJECTS)
    assert set(rendered.groups) <= {c.name for c in viewpoint_cameras()}
    for mask in rendered.masks:
        assert mask.dtype == bool and mask.shape == (180, 240)
        assert mask.sum() >= 40
        assert not (mask[0].any() or mask[-1].any() or mask[:, 0].any() or mask[:, -1].any())
    size = rendered.extras["metric_size"]
    balls = size[rendered.labels == "tennis_ball"]
    # sqrt(area) of a 65 mm disc is 0.886 * 65 mm = 58 mm (perspective adds a little)
    assert np.all((balls > 0.05) & (balls < 0.065)), balls


def test_cache_is_written_once_and_reloads_identically(rendered, cache, monkeypatch):
    files = list(cache.glob("silhouettes-*.npz"))
    assert len(files) == 1 and not list(cache.glob("*.tmp"))
    monkeypatch.setenv("SCORBOT_GYM_CACHE", str(cache))
    again = render_catalogue_silhouettes(OBJECTS, n_per_object=PER_OBJECT, seed=11)
    for a, b in zip(again.masks, rendered.masks, strict=True):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(again.labels, rendered.labels)
    assert again.sources == rendered.sources


def test_rendering_is_seeded(rendered):
    fresh = render_catalogue_silhouettes(OBJECTS[:1], n_per_object=3, seed=11, use_cache=False)
    assert fresh.sources == rendered.sources[:3]  # same draws for the first object
    for a, b in zip(fresh.masks, rendered.masks[:3], strict=True):
        np.testing.assert_array_equal(a, b)


def test_unknown_object_lists_valid_names():
    with pytest.raises(KeyError, match="valid objects"):
        render_catalogue_silhouettes(["teapot"], n_per_object=1, use_cache=False)


def test_flr_recognises_rendered_objects(rendered):
    X = shape_descriptors(rendered.masks)
    even = np.arange(len(X)) % 2 == 0
    clf = FLRClassifier().fit(X[even], rendered.labels[even])
    assert clf.score(X[~even], rendered.labels[~even]) >= 0.75


@pytest.mark.slow
def test_shapes_eval_cli_on_rendered_objects(rendered, cache, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("SCORBOT_GYM_CACHE", str(cache))
    out_json, out_png = tmp_path / "r.json", tmp_path / "cm.png"
    argv = ["shapes", "eval", "--objects", ",".join(OBJECTS), "--per-object", str(PER_OBJECT),
            "--seed", "11", "--with-size", "--json", str(out_json),
            "--png", str(out_png)]  # fmt: skip
    assert main(argv) == 0
    result = json.loads(out_json.read_text())
    assert result["layout"] == "rendered" and result["n_features"] == 74
    assert result["n_train"] + result["n_test"] == len(rendered)
    assert set(result["classifiers"]) == {"flr", "knn", "svm"}
    for r in result["classifiers"].values():
        assert np.sum(r["confusion"]) == result["n_test"]
    assert out_png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "flr  accuracy" in capsys.readouterr().out


def test_unknown_viewpoints_are_reported():
    with pytest.raises(ValueError, match="viewpoints must be one of ring, scene"):
        render_catalogue_silhouettes(["box"], n_per_object=1, viewpoints="orbit", use_cache=False)
