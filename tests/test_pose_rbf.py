"""Stage e: RBF regressors (k-means RBF network and scipy's RBFInterpolator)."""

import numpy as np
import pytest
from sklearn.base import clone

from pose.manifold.regressors import RBFNetwork, ScipyRBF


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


def _broadcast_fit(X, y, **params):
    """The network fitted with the one-broadcast distances the blocked ones replaced: the
    specification they must reproduce bit for bit (so saved models and sweep figures stay)."""
    m = RBFNetwork(**params)
    m.fit(X, y)
    c = m.centers_
    dc = np.linalg.norm(c[:, None] - c[None], axis=2)
    np.fill_diagonal(dc, np.inf)
    nn = np.sort(dc, axis=1)[:, : min(m.n_neighbors, len(c) - 1)]
    widths = m.width_scale * nn.mean(axis=1)
    Z = (X - m.x_mean_) / m.x_scale_
    e = -((Z[:, None, :] - c[None]) ** 2).sum(axis=2) / (2 * widths**2)
    if m.normalized:
        e = np.exp(e - e.max(axis=1, keepdims=True))
        P = np.c_[e / e.sum(axis=1, keepdims=True), np.ones(len(Z))]
    else:
        P = np.c_[np.exp(e), np.ones(len(Z))]
    reg = m.alpha * np.eye(P.shape[1])
    reg[-1, -1] = 0.0
    return m, widths, np.linalg.solve(P.T @ P + reg, P.T @ y)


@pytest.mark.parametrize("n, normalized", [(150, True), (150, False), (70, True)])
def test_blocked_distances_give_the_broadcast_bits(n, normalized):
    rng = np.random.default_rng(n)
    X, y = rng.normal(size=(n, 9)), rng.normal(size=(n, 3))
    # 150 rows > 100 centres: k-means centres; 70 rows: every sample a centre (the manifold's
    # case); 150 rows span three blocks of 64
    m, widths, weights = _broadcast_fit(X, y, n_centers=100, width_scale=0.1, alpha=1e-4,
                                        standardize=False, normalized=normalized)  # fmt: skip
    assert np.array_equal(m.widths_, widths) and np.array_equal(m.weights_, weights)
    Xt = rng.normal(size=(130, 9))  # more rows than one block
    Zt = (Xt - m.x_mean_) / m.x_scale_
    d2 = ((Zt[:, None, :] - m.centers_[None]) ** 2).sum(axis=2)
    e = -d2 / (2 * m.widths_**2)
    if normalized:
        e = np.exp(e - e.max(axis=1, keepdims=True))
        expected = np.c_[e / e.sum(axis=1, keepdims=True), np.ones(len(Zt))] @ m.weights_
    else:
        expected = np.c_[np.exp(e), np.ones(len(Zt))] @ m.weights_
    assert np.array_equal(m.predict(Xt), expected)
