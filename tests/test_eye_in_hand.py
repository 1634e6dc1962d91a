"""The pose from the camera on the hand: trained from the home pose, calibrated every step."""

import numpy as np
import pytest

from scorbot_gym.envs.factory import make_env
from scorbot_gym.evaluation import run_episodes
from scorbot_gym.perception.training import train_models
from scorbot_gym.policies import ScriptedGraspPolicy


@pytest.mark.slow
def test_grasp_from_the_hand_camera_with_depth_masks():
    models = train_models(["box"], n_views=72, camera="eye_in_hand", progress=False)[0]
    assert models.meta["camera"] == "eye_in_hand"
    env = make_env(
        pose="manifold", pose_kwargs={"models": models, "segmenter": "depth"}, objects=["box"]
    )
    try:
        assert "eye_in_hand_depth" in env.unwrapped.observation_space.spaces
        results = run_episodes(env, ScriptedGraspPolicy.for_env(env), 2, seed=0, progress=False)
    finally:
        env.close()
    assert all(r.success for r in results), [r.failure_cause for r in results]
    for r in results:
        p = r.perception
        assert (
            p["first_valid"] and p["valid"] > 0.3 * p["estimates"]
        )  # hidden by its fingers near the end
        assert p["median_pos_err_cm"] < 1.0 and p["median_rot_err_deg"] < 5.0
        assert not p["privileged"]
    assert np.isfinite(results[0].perception["median_estimate_ms"])
