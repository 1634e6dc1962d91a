import pytest

from pose.manifold.estimator import PoseManifoldEstimator
from pose.registry import estimator_names, make_estimator, register_estimator


def test_make_by_name_with_params_and_clear_errors():
    est = make_estimator("manifold", bunches__n_bunches=6)
    assert isinstance(est, PoseManifoldEstimator) and est.bunches.n_bunches == 6
    assert "manifold" in estimator_names()
    with pytest.raises(ValueError, match="registered: .*manifold"):
        make_estimator("nope")
    with pytest.raises(ValueError, match="already registered"):
        register_estimator("manifold", PoseManifoldEstimator)
