"""The Fuzzy Lattice Reasoning classifier: lattice maths, learning, estimator contract."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.base import clone
from sklearn.model_selection import train_test_split

from pose.shape.baselines import FeatureWeights, make_classifiers, make_knn, make_svm
from pose.shape.descriptors import (
    AMI_SLICE,
    ART_SLICE,
    FOURIER_SLICE,
    block_weights,
    shape_descriptors,
)
from pose.shape.flr import FLRClassifier, calcin, in_distance, point_in_distances
from pose.shape.silhouettes import synthetic_dataset


@pytest.fixture(scope="module")
def shapes_split():
    data = synthetic_dataset(n_per_class=16, size=80, seed=3)
    X = shape_descriptors(data.masks)
    return train_test_split(X, data.labels, test_size=0.5, random_state=0, stratify=data.labels)


def test_calcin_levels_follow_the_empirical_distribution():
    pop = np.arange(101, dtype=float)[:, None]  # 0..100
    ins = calcin(pop, n_levels=4)  # h = 1/8, 3/8, 5/8, 7/8
    assert ins.shape == (4, 2, 1)
    h = (np.arange(4) + 0.5) / 4
    np.testing.assert_allclose(ins[:, 0, 0], 100 * h / 2)
    np.testing.assert_allclose(ins[:, 1, 0], 100 * (1 - h / 2))
    # nested: higher levels are sub-intervals of lower ones
    assert np.all(np.diff(ins[:, 0, 0]) >= 0) and np.all(np.diff(ins[:, 1, 0]) <= 0)


def test_lattice_metric_between_point_and_interval():
    ins = np.array([[[[0.2], [0.6]]]])  # one rule, one level, interval [0.2, 0.6]
    X = np.array([[0.4], [0.9], [0.2]])
    d = point_in_distances(X, ins, np.ones(1))[:, 0]
    # |x - a| + |x - b|: inside -> the width; outside -> width + 2 * the gap
    np.testing.assert_allclose(d, [0.4, 1.0, 0.4])
    assert in_distance(ins[0], ins[0], np.ones(1)) == 0.0


def test_vigilance_one_keeps_every_sample_and_acts_as_nearest_neighbour():
    X = np.array([[0.0, 0.0], [0.1, 0.0], [1.0, 1.0], [0.9, 1.0]])
    y = np.array(["a", "a", "b", "b"])
    clf = FLRClassifier(vigilance=1.0, consolidate=False).fit(X, y)
    assert clf.n_rules_learned_ == 4
    assert list(clf.predict([[0.05, 0.1], [0.8, 0.9]])) == ["a", "b"]


def test_lower_vigilance_gives_fewer_rules_and_consolidation_merges(shapes_split):
    X_tr, _, y_tr, _ = shapes_split
    strict = FLRClassifier(vigilance=0.98, consolidate=False).fit(X_tr, y_tr)
    loose = FLRClassifier(vigilance=0.7, consolidate=False).fit(X_tr, y_tr)
    merged = FLRClassifier(vigilance=0.98, consolidate=True).fit(X_tr, y_tr)
    assert loose.n_rules_learned_ < strict.n_rules_learned_
    assert len(merged.rule_labels_) < strict.n_rules_learned_
    assert merged.rule_sizes_.sum() == len(X_tr)
    assert merged.n_rules_learned_ == strict.n_rules_learned_


def test_flr_and_baselines_recognise_synthetic_shapes(shapes_split):
    X_tr, X_te, y_tr, y_te = shapes_split
    for name, clf in make_classifiers(seed=0).items():
        acc = clf.fit(X_tr, y_tr).score(X_te, y_te)
        assert acc >= 0.9, f"{name}: {acc:.3f}"


def test_estimator_contract(shapes_split):
    X_tr, X_te, y_tr, _ = shapes_split
    clf = FLRClassifier(vigilance=0.8, n_levels=4, random_state=7)
    assert clf.get_params()["vigilance"] == 0.8
    clf.set_params(vigilance=0.85)
    assert clf.vigilance == 0.85
    assert not hasattr(clf, "rule_ins_")  # __init__ only stores
    clf.fit(X_tr, y_tr)
    before = clf.rule_ins_.copy()
    p1 = clf.predict(X_te)
    p2 = clf.predict(X_te)
    np.testing.assert_array_equal(p1, p2)
    np.testing.assert_array_equal(before, clf.rule_ins_)  # predict is pure
    assert set(p1) <= set(clf.classes_)
    assert clf.class_distances(X_te).shape == (len(X_te), len(clf.classes_))
    twin = clone(clf).fit(X_tr, y_tr)  # same seed -> same model
    np.testing.assert_array_equal(twin.rule_ins_, clf.rule_ins_)


def test_seed_changes_presentation_order(shapes_split):
    X_tr, _, y_tr, _ = shapes_split
    a = FLRClassifier(vigilance=0.8, consolidate=False, random_state=0).fit(X_tr, y_tr)
    b = FLRClassifier(vigilance=0.8, consolidate=False, random_state=1).fit(X_tr, y_tr)
    assert a.n_rules_learned_ != b.n_rules_learned_ or not np.array_equal(a.rule_ins_, b.rule_ins_)


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ({"vigilance": 0.0}, "vigilance"),
        ({"vigilance": 1.5}, "vigilance"),
        ({"n_levels": 0}, "n_levels"),
        ({"feature_weights": [1.0, -1.0]}, "feature_weights"),
    ],
)
def test_bad_hyperparameters_are_reported(params, message):
    with pytest.raises(ValueError, match=message):
        FLRClassifier(**params).fit([[0.0, 1.0], [1.0, 0.0]], [0, 1])


def test_predict_before_fit_and_wrong_width_fail_clearly(shapes_split):
    from sklearn.exceptions import NotFittedError

    with pytest.raises(NotFittedError):
        FLRClassifier().predict([[0.0, 1.0]])
    clf = FLRClassifier().fit([[0.0, 1.0], [1.0, 0.0]], [0, 1])
    with pytest.raises(ValueError, match="features"):
        clf.predict([[0.0, 1.0, 2.0]])


def test_baselines_are_scaled_weighted_pipelines():
    for pipe in (make_knn(), make_svm()):
        assert [s[0] for s in pipe.steps[:2]] == ["standardscaler", "featureweights"]
    X = np.array([[0.0, 1.0], [2.0, 3.0]])
    np.testing.assert_array_equal(FeatureWeights([2.0, 0.5]).fit_transform(X), [[0, 0.5], [4, 1.5]])
    np.testing.assert_array_equal(FeatureWeights().fit_transform(X), X)
    with pytest.raises(ValueError, match="2 finite non-negative"):
        FeatureWeights([1.0, 2.0, 3.0]).fit(X)


def test_block_weights_follow_the_descriptor_layout():
    w = block_weights(art=2.0, ami=3.0, n_extra=1)
    assert w.shape == (74,)
    assert np.all(w[FOURIER_SLICE] == 1) and np.all(w[ART_SLICE] == 2) and np.all(w[AMI_SLICE] == 3)
    assert w[-1] == 1.0


def test_passes_scikit_learn_estimator_checks():
    from sklearn.utils.estimator_checks import check_estimator

    results = check_estimator(FLRClassifier(), on_fail=None)
    failed = [r["check_name"] for r in results if r["status"] == "failed"]
    assert not failed, failed
