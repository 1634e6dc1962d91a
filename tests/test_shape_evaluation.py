"""The held-out comparison used by ``shapes eval`` and the benchmark."""

from __future__ import annotations

import numpy as np
import pytest

from pose.shape.descriptors import shape_descriptors
from pose.shape.evaluation import evaluate, split_indices
from pose.shape.silhouettes import synthetic_dataset


@pytest.fixture(scope="module")
def shapes():
    data = synthetic_dataset(n_per_class=8, size=64, seed=9)
    return shape_descriptors(data.masks), data.labels


def test_given_split_and_per_group_report(shapes):
    X, y = shapes
    idx = np.arange(len(y))
    train, test = idx[idx % 4 != 0], idx[idx % 4 == 0]
    groups = np.where(idx % 8 == 0, "even8", "other")
    result = evaluate(X, y, split=(train, test), report_groups=groups, tune=False)
    assert result["split"] == "given"
    assert (result["n_train"], result["n_test"]) == (len(train), len(test))
    for r in result["classifiers"].values():
        assert set(r["accuracy_per_group"]) == {"even8", "other"}
        assert np.sum(r["confusion"]) == len(test)
        assert np.trace(r["confusion"]) / len(test) == pytest.approx(r["accuracy"])
    assert result["best_baseline"] in ("knn", "svm")


def test_split_is_seeded_stratified_and_groups_stay_whole(shapes):
    _, y = shapes
    a = split_indices(y, None, 0.5, seed=3)
    b = split_indices(y, None, 0.5, seed=3)
    np.testing.assert_array_equal(a[1], b[1])
    assert set(np.unique(y[a[1]], return_counts=True)[1]) == {4}
    groups = np.repeat(np.arange(len(y) // 2), 2)
    train, test = split_indices(y, groups, 0.5, seed=0)
    assert not set(groups[train]) & set(groups[test])


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [({"test_size": 1.5}, "test_size"), ({"test_size": 0.0}, "test_size")],
)
def test_bad_split_arguments(shapes, kwargs, message):
    X, y = shapes
    with pytest.raises(ValueError, match=message):
        evaluate(X, y, **kwargs)


def test_a_class_with_one_silhouette_cannot_be_split(shapes):
    X, y = shapes
    y = y.copy()
    y[0] = "lonely"
    with pytest.raises(ValueError, match="at least 2 silhouettes"):
        evaluate(X, y)
