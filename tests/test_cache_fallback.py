"""An unwritable cache is not fatal (issue 35, item 14): the default cache falls back to a
temporary folder with a one-line warning; a cache folder given explicitly is a one-line error.

Tests run as root, where permission bits do not stop writes: an unwritable folder is made as a
path through a regular file, which no user can create; the permission case runs as non-root."""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import scorbot_gym.data as data
from scorbot_gym.cli import main
from scorbot_gym.objects import load_object_model


@pytest.fixture()
def unwritable_cache(tmp_path, monkeypatch):
    """``$SCORBOT_GYM_CACHE`` under a regular file, and no folder checked yet."""
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    monkeypatch.setattr(data, "_usable", {})
    load_object_model.cache_clear()  # objects loaded by earlier tests: read the cache again
    monkeypatch.setenv(data.CACHE_ENV, str(blocker / "cache"))
    return blocker / "cache"


def _fallback_warning(record: list[warnings.WarningMessage], folder: Path) -> str:
    messages = [str(w.message) for w in record if issubclass(w.category, RuntimeWarning)]
    assert len(messages) == 1, messages
    assert messages[0].startswith(f"cache folder {folder} is not writable (Not a directory)")
    assert "\n" not in messages[0]
    return messages[0]


def test_make_and_reset_with_an_unwritable_cache_falls_back_to_a_temporary_one(
    unwritable_cache,
):
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        env = gym.make(
            "ScorbotGrasp-v0", object_name="box", cameras=["top"], image_width=64, image_height=48
        )
        obs, _ = env.reset(seed=0)
        env.close()
    _fallback_warning(record, unwritable_cache)
    assert obs["top_rgb"].any()
    fallback = data.default_cache_dir()
    assert fallback != unwritable_cache and fallback.is_dir() and os.access(fallback, os.W_OK)
    assert os.environ[data.CACHE_ENV] == str(fallback)  # worker processes inherit it


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes through permission bits")
def test_a_read_only_cache_falls_back_to_a_temporary_one(tmp_path, monkeypatch):
    folder = tmp_path / "read-only"
    folder.mkdir(mode=0o555)
    monkeypatch.setattr(data, "_usable", {})
    monkeypatch.setenv(data.CACHE_ENV, str(folder))
    with pytest.warns(RuntimeWarning, match="is not writable"):
        assert data.default_cache_dir() != folder


def test_a_writable_cache_is_used_as_it_is(tmp_path, monkeypatch):
    monkeypatch.setattr(data, "_usable", {})
    monkeypatch.setenv(data.CACHE_ENV, str(tmp_path / "new" / "cache"))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert data.default_cache_dir() == tmp_path / "new" / "cache"
    assert list((tmp_path / "new" / "cache").iterdir()) == []  # the probe left nothing


def test_an_explicit_unwritable_cache_dir_is_a_one_line_error(tmp_path, capsys):
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    with pytest.raises(ValueError, match=r"cache folder .*a-file/c is not writable \(Not a dir"):
        data.cache_folder(blocker / "c")
    argv = ["pose", "train", "--objects", "box", "--quiet", "--cache-dir", str(blocker / "c")]
    argv += ["--out", str(tmp_path / "m.npz")]
    assert main(argv) == 2  # a usage error
    err = capsys.readouterr().err.strip()
    assert err.startswith("scorbot-gym pose train: error: cache folder") and "\n" not in err
    assert not (tmp_path / "m.npz").exists()


@pytest.mark.slow
def test_pose_train_and_a_manifold_rollout_run_with_an_unwritable_cache(
    unwritable_cache, tmp_path, capsys
):
    models = tmp_path / "box.npz"
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        argv = ["pose", "train", "--objects", "box", "--views", "24", "--quiet", "--jobs", "1"]
        assert main([*argv, "--out", str(models)]) == 0
    _fallback_warning(record, unwritable_cache)
    assert models.is_file()
    argv = ["rollout", "--pose", "manifold", "--pose-model", str(models), "--objects", "box"]
    argv += ["--episodes", "1", "--estimate-every", "50", "--no-progress"]
    assert main(argv) == 0
    assert "pose estimates valid" in capsys.readouterr().out
    np.testing.assert_equal(data.default_cache_dir().is_dir(), True)
