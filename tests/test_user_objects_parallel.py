"""User-registered objects reach spawned worker processes (issue 37, item 6)."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from scorbot_gym.objects import CATALOGUE, install_objects, user_objects
from scorbot_gym.perception.training import train_models


def test_user_objects_lists_registrations_only(user_object):
    assert user_objects() == (user_object,)
    copy = pickle.loads(pickle.dumps(user_objects()))  # what a pool initializer receives
    CATALOGUE.pop("user_block")
    install_objects(copy)
    assert CATALOGUE["user_block"] == user_object


@pytest.mark.slow
def test_train_models_in_parallel_with_a_user_object(user_object, tmp_path):
    models, info = train_models(
        ["user_block", "box"], n_views=12, jobs=2, progress=False, cache_dir=str(tmp_path)
    )
    assert set(models.object_names) == {"user_block", "box"}
    assert info["user_block"]["views"] >= 12
    serial, _ = train_models(["user_block"], n_views=12, progress=False, cache_dir=str(tmp_path))
    a = models["user_block"].to_arrays()
    b = serial["user_block"].to_arrays()
    assert all(np.array_equal(a[k], b[k]) for k in a if isinstance(a[k], np.ndarray))
