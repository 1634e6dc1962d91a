"""Stage e: RBF regressors (k-means RBF network and scipy's RBFInterpolator)."""

import numpy as np
import pytest
from sklearn.base import clone

from pose.rbf import RBFNetwork, ScipyRBF


def _data(n=300, seed=0):
    rng = np.random.default_rng(seed)
    X = rng.uniform(-2, 2, (n, 2))
    y = np.c_[np.sin(X[:, 0]) * np.cos(X[:, 1]), X[:, 0] * X[:, 1] / 4]
    return X, y


@pytest.mark.parametrize("model", [RBFNetwork(n_centers=40, alpha=1e-6), ScipyRBF()])
def test_fits_a_smooth_function(model):
    X, y = _data()
    Xt, yt = _data(100, seed=1)
    err = np.abs(model.fit(X, y).predict(Xt) - yt)
    assert np.sqrt((err**2).mean()) < 0.04  # targets have std 0.27
    assert err.max() < 0.15


def test_sklearn_contract_and_seed():
    m = RBFNetwork(n_centers=10, random_state=3)
    assert m.get_params()["n_centers"] == 10
    m.set_params(n_centers=12)
    assert clone(m).n_centers == 12 and not hasattr(clone(m), "weights_")
    X, y = _data(100)
    a = RBFNetwork(n_centers=10, random_state=3).fit(X, y)
    b = RBFNetwork(n_centers=10, random_state=3).fit(X, y)
    np.testing.assert_array_equal(a.predict(X), b.predict(X))


@pytest.mark.parametrize("cls", [RBFNetwork, ScipyRBF])
def test_arrays_round_trip(cls):
    X, y = _data(80)
    m = cls().fit(X, y)
    m2 = cls().load_arrays(m.to_arrays())
    np.testing.assert_allclose(m2.predict(X), m.predict(X))


def test_bad_input_is_explained():
    with pytest.raises(ValueError, match="X has 3 rows but y has 2"):
        RBFNetwork().fit(np.zeros((3, 2)), np.zeros(2))
    with pytest.raises(ValueError, match="NaN"):
        RBFNetwork().fit(np.full((3, 2), np.nan), np.zeros(3))
