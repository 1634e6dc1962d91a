"""The env wrapped with the pose-manifold source keeps Gymnasium's contract (issue 35, items 9
and 10): ``check_env`` passes with either segmenter (wall-clock timings are kept out of the
step's ``info``), and the env pickles and deep-copies after ``reset`` (the background
segmenter's arm renderer drops its GL contexts and makes them again)."""

from __future__ import annotations

import copy
import pickle

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from scorbot_gym.envs.factory import make_env
from scorbot_gym.perception.training import train_models

pytestmark = pytest.mark.slow


@pytest.fixture(scope="session")
def box_models(tmp_path_factory):
    """A model file of the box alone (the top camera at 320 x 240, the source's default), as
    ``scorbot-gym pose train`` writes it: given by path, the env's spec can rebuild the env
    (``check_env`` does)."""
    path = tmp_path_factory.mktemp("models") / "box.npz"
    train_models(["box"], n_views=72, progress=False)[0].save(path)
    return str(path)


def _manifold_env(models, segmenter: str, **kwargs):
    return make_env(
        pose="manifold",
        pose_kwargs={"models": models, "segmenter": segmenter},
        object_name="box",
        **kwargs,
    )


@pytest.mark.parametrize("segmenter", ["background", "privileged"])
def test_check_env_passes_on_the_wrapped_manifold_env(box_models, segmenter):
    env = _manifold_env(box_models, segmenter)
    check_env(env, skip_render_check=True)
    _, info = env.reset(seed=0)
    assert info["perception"]["estimated"] and info["perception"]["valid"]
    assert "total_ms" not in info["perception"] and "timings_ms" not in info["perception"]
    timings = env.perception_timings
    assert timings["total_ms"] > 0 and timings["timings_ms"]["estimate"] > 0
    env.close()


def test_timings_in_info_is_an_opt_in(box_models):
    env = _manifold_env(box_models, "privileged", timings_in_info=True, estimate_every=2)
    _, info = env.reset(seed=0)
    assert info["perception"]["total_ms"] == env.perception_timings["total_ms"] > 0
    _, _, _, _, info = env.step(np.zeros(6, np.float32))  # no estimate at this step
    assert info["perception"]["total_ms"] is None and env.perception_timings is None
    env.close()
    with pytest.raises(ValueError, match="timings_in_info must be True or False, got 'yes'"):
        _manifold_env(box_models, "privileged", timings_in_info="yes")


@pytest.mark.parametrize("copier", [lambda e: pickle.loads(pickle.dumps(e)), copy.deepcopy])
def test_manifold_env_pickles_and_copies_after_reset(box_models, copier):
    env = _manifold_env(box_models, "background")
    env.reset(seed=1)  # the arm renderer holds a GL context now
    clone = copier(env)
    action = np.full(6, 0.2, np.float32)
    runs = []
    for e in (env, clone):
        obs, info = e.reset(seed=4)
        steps = [obs] + [e.step(action)[0] for _ in range(3)]
        runs.append((steps, info["perception"]["valid"]))
    assert runs[0][1] and runs[1][1]  # both estimated a valid pose
    for a, b in zip(runs[0][0], runs[1][0], strict=True):
        for key in a:
            np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    clone.close()
    env.close()
