"""Fuzzy Lattice Reasoning (FLR) classifier on Intervals' Numbers.

Lattice-computing background (Kaburlasos et al.):

* An *interval* ``[a, b]`` of reals lives in a lattice with join ``[min a, max b]``. With the
  positive valuation ``v(x) = x`` and the dual isomorphic function ``theta(x) = 1 - x`` an
  interval's valuation is ``v([a, b]) = 1 - a + b`` and the lattice metric between two intervals
  is ``d([a, b], [c, d]) = |a - c| + |b - d|``. The fuzzy inclusion measure is
  ``sigma(x <= u) = v(u) / v(x v u)``.
* An *Intervals' Number* (IN) is a nested family of intervals ``F(h)``, one per level
  ``h in (0, 1]``. CALCIN induces an IN from a population of numbers so that it mirrors the
  empirical distribution: ``F(h) = [q(h/2), q(1 - h/2)]`` with ``q`` the empirical quantile
  (support at h -> 0, median at h = 1). The metric between INs is
  ``D(F, G) = integral_0^1 d(F(h), G(h)) dh`` (here a midpoint sum over ``n_levels`` levels);
  between N-tuples of INs it is the (weighted) sum over the N dimensions.

The classifier (FLRtypeII):

1. *Learning.* Training samples (features min-max scaled on the training set) are presented
   in a seeded random order as trivial hyperboxes. Each rule is a labelled hyperbox holding
   the population of samples it has absorbed. A sample competes for the rules by fuzzy
   inclusion ``sigma``; the best rule is tried first and assimilates the sample (hyperbox
   join) if it has the sample's class and the join passes the vigilance test
   ``N / v(x v rule) >= vigilance`` (N features; 1 means "no growth at all", smaller values
   let a rule span a mean interval width up to ``1/vigilance - 1``); otherwise it is reset
   and the next rule is tried (as in fuzzy ARTMAP); if none qualifies the sample founds a new
   rule. Every rule's population, per feature, is then summarised by CALCIN as an IN.
2. *Generalization* (FLR's name for classifying new data). A test sample (a trivial IN per
   feature) goes to the class of the rule at the smallest IN distance.
3. *Optional consolidation* (``consolidate=True``, our addition, off by default). Rules of
   one class are merged greedily, closest pair first, whenever the merged rule (IN of the
   union of both populations) makes no more leave-one-out training errors. It shrinks the
   rule base several-fold, but on the rendered catalogue silhouettes it costs accuracy
   (broad INs lose to narrow ones under the IN metric; ``benchmarks/shape_recognition.py``
   measures both), hence the default.

References
----------
* V. G. Kaburlasos, I. N. Athanasiadis, P. A. Mitkas, "Fuzzy lattice reasoning (FLR)
  classifier and its application for ambient ozone estimation", Int. J. Approximate
  Reasoning 45(1) (2007) 152-188.
* V. G. Kaburlasos, S. E. Papadakis, G. A. Papakostas, "Lattice computing extension of the
  FAM neural classifier for human facial expression recognition", IEEE Trans. Neural Netw.
  Learn. Syst. 24(10) (2013) 1526-1538 (FLRtypeI / FLRtypeII, INs from populations).
* V. G. Kaburlasos, T. Pachidis, "A lattice-computing ensemble for reasoning based on formal
  fusion of disparate data types, and an industrial dispensing application", Information
  Fusion 16 (2014) 68-83.
* V. G. Kaburlasos, "Towards a Unified Modeling and Knowledge-Representation based on Lattice
  Theory", Springer 2006 (Intervals' Numbers, CALCIN).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.distance import cdist
from sklearn.base import BaseEstimator, ClassifierMixin
from sklearn.utils.multiclass import check_classification_targets
from sklearn.utils.validation import check_is_fitted, validate_data


def calcin(population: np.ndarray, n_levels: int) -> np.ndarray:
    """Intervals' Numbers of a population: ``(n_levels, 2, D)`` lower/upper ends per level.

    ``population`` is ``(M, D)``: M samples of D features; each feature gets its own IN.
    Level ``l`` is ``h = (l + 0.5) / n_levels`` and its interval ``[q(h/2), q(1 - h/2)]``.
    """
    pop = np.atleast_2d(np.asarray(population, dtype=np.float64))
    h = (np.arange(n_levels) + 0.5) / n_levels
    lo = np.quantile(pop, h / 2.0, axis=0)
    hi = np.quantile(pop, 1.0 - h / 2.0, axis=0)
    return np.stack([lo, hi], axis=1)


def point_in_distances(X: np.ndarray, ins: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """IN metric between samples (trivial INs) and rules: ``(n_samples, n_rules)``.

    ``X`` is ``(n, D)``; ``ins`` is ``(R, L, 2, D)``. For a point x and interval [a, b] the
    lattice metric is ``|x - a| + |x - b|``; levels are averaged, features weighted and summed.
    That is a weighted city-block distance between x repeated 2L times and the rule's
    flattened interval ends, which is how it is computed.
    """
    n_rules, n_levels, _, dim = ins.shape
    w = np.tile(weights, 2 * n_levels) / n_levels
    rules = ins.reshape(n_rules, 2 * n_levels * dim) * w
    return cdist(np.tile(X, 2 * n_levels) * w, rules, metric="cityblock")


def in_distance(a: np.ndarray, b: np.ndarray, weights: np.ndarray) -> float:
    """IN metric between two N-tuples of INs of shape ``(L, 2, D)``."""
    return float(np.abs(a - b).sum(axis=1).mean(axis=0) @ weights)


def in_distance_matrix(ins: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Pairwise IN metric between rules ``(R, L, 2, D)``: ``(R, R)``."""
    n_rules, n_levels, _, _ = ins.shape
    w = np.tile(weights, 2 * n_levels) / n_levels
    flat = ins.reshape(n_rules, -1) * w
    return cdist(flat, flat, metric="cityblock")


_LOO_MAX = 30


def _nearest3(dist: np.ndarray) -> np.ndarray:
    """Column indices of each row's (up to) three smallest entries, nearest first."""
    k = min(3, dist.shape[1])
    part = np.argpartition(dist, k - 1, axis=1)[:, :k]
    order = np.argsort(np.take_along_axis(dist, part, axis=1), axis=1, kind="stable")
    return np.take_along_axis(part, order, axis=1)


class FLRClassifier(ClassifierMixin, BaseEstimator):
    """Fuzzy Lattice Reasoning classifier (FLRtypeII) with Intervals' Number rules.

    Parameters
    ----------
    vigilance : float in (0, 1]
        Assimilation threshold of the learning stage: a rule may absorb a sample only if
        ``N / v(sample v rule) >= vigilance``. 1 keeps every distinct sample as its own rule
        (then prediction is 1-nearest-neighbour under the lattice L1 metric); smaller values
        give fewer, coarser rules.
    n_levels : int >= 1
        Number of levels ``h`` at which Intervals' Numbers are sampled.
    consolidate : bool
        Run the rule-merging stage after learning (see the module docstring).
    merge_neighbors : int >= 1
        In consolidation, each rule is tried for merging with this many of its nearest
        same-class rules (bounds the cost at ``R * merge_neighbors`` trials).
    feature_weights : array-like of shape (n_features,) or None
        Non-negative weight of each feature in the IN metric; None weights all features 1.
    random_state : int or None
        Seed of the presentation order of the training samples.

    Attributes
    ----------
    classes_ : ndarray of shape (n_classes,)
    rule_ins_ : ndarray of shape (n_rules, n_levels, 2, n_features), the rules' INs
    rule_labels_ : ndarray of shape (n_rules,), index into ``classes_``
    rule_sizes_ : ndarray of shape (n_rules,), population size of each rule
    n_rules_learned_ : int, rules after the learning stage (before consolidation)
    """

    def __init__(
        self,
        vigilance: float = 0.97,
        n_levels: int = 8,
        consolidate: bool = False,
        merge_neighbors: int = 5,
        feature_weights=None,
        random_state: int | None = 0,
    ) -> None:
        self.vigilance = vigilance
        self.n_levels = n_levels
        self.consolidate = consolidate
        self.merge_neighbors = merge_neighbors
        self.feature_weights = feature_weights
        self.random_state = random_state

    # -- fitting -------------------------------------------------------------------------

    def _check_params(self, n_features: int) -> np.ndarray:
        if not (isinstance(self.vigilance, int | float) and 0.0 < self.vigilance <= 1.0):
            raise ValueError(f"vigilance must be a number in (0, 1], got {self.vigilance!r}")
        if not (isinstance(self.n_levels, int | np.integer) and self.n_levels >= 1):
            raise ValueError(f"n_levels must be an integer >= 1, got {self.n_levels!r}")
        if not (isinstance(self.merge_neighbors, int | np.integer) and self.merge_neighbors >= 1):
            raise ValueError(
                f"merge_neighbors must be an integer >= 1, got {self.merge_neighbors!r}"
            )
        if self.feature_weights is None:
            return np.ones(n_features)
        w = np.asarray(self.feature_weights, dtype=np.float64)
        if w.shape != (n_features,) or not np.all(np.isfinite(w)) or np.any(w < 0):
            raise ValueError(
                f"feature_weights must be {n_features} finite non-negative numbers, "
                f"got shape {w.shape}"
            )
        return w

    def fit(self, X, y) -> FLRClassifier:
        X, y = validate_data(self, X, y)
        check_classification_targets(y)
        weights = self._check_params(X.shape[1])
        self.classes_, y_idx = np.unique(y, return_inverse=True)
        self.scale_min_ = X.min(axis=0)
        span = X.max(axis=0) - self.scale_min_
        self.scale_span_ = np.where(span > 0, span, 1.0)
        Xs = self._scale(X)

        members = self._learn(Xs, y_idx, np.random.default_rng(self.random_state))
        self.n_rules_learned_ = len(members)
        labels = np.array([y_idx[m[0]] for m in members])
        if self.consolidate:
            members, labels, ins = self._consolidate(Xs, y_idx, members, labels, weights)
        else:
            ins = np.stack([calcin(Xs[m], self.n_levels) for m in members])
        self.weights_ = weights
        self.rule_ins_ = ins
        self.rule_labels_ = labels
        self.rule_sizes_ = np.array([len(m) for m in members])
        return self

    def _scale(self, X: np.ndarray) -> np.ndarray:
        return (X - self.scale_min_) / self.scale_span_

    def _learn(self, Xs: np.ndarray, y_idx: np.ndarray, rng: np.random.Generator) -> list:
        """FLR learning stage: list of member-index arrays, one per rule."""
        n, dim = Xs.shape
        lo = np.empty((0, dim))
        hi = np.empty((0, dim))
        rule_label: list[int] = []
        members: list[list[int]] = []
        for i in rng.permutation(n):
            x = Xs[i]
            j_lo, j_hi = np.minimum(lo, x), np.maximum(hi, x)  # x joined with every rule
            v_join = (1.0 - j_lo + j_hi).sum(axis=1)
            sigma = (1.0 - lo + hi).sum(axis=1) / v_join  # fuzzy inclusion sigma(x <= rule)
            # competition: best rule first; a wrong class or a failed vigilance test resets it
            winner = next(
                (r for r in np.argsort(-sigma, kind="stable")
                 if rule_label[r] == y_idx[i] and dim / v_join[r] >= self.vigilance),
                None,
            )  # fmt: skip
            if winner is not None:
                lo[winner], hi[winner] = j_lo[winner], j_hi[winner]
                members[winner].append(i)
                continue
            lo = np.vstack([lo, x])
            hi = np.vstack([hi, x])
            rule_label.append(int(y_idx[i]))
            members.append([i])
        return [np.array(m) for m in members]

    def _rule_column(self, Xs: np.ndarray, pop: np.ndarray, weights: np.ndarray):
        """The rule's IN and every training sample's distance to it, leave-one-out for members.

        A member's distance is to the IN of the population without it (``inf`` when it is the
        only member), so a rule never vouches for the samples that built it. Populations
        larger than ``_LOO_MAX`` use the full IN for members too (one sample barely moves it).
        """
        ins = calcin(Xs[pop], self.n_levels)
        col = point_in_distances(Xs, ins[None], weights)[:, 0]
        if len(pop) == 1:
            col[pop] = np.inf
        elif len(pop) <= _LOO_MAX:
            for j, i in enumerate(pop):
                loo = calcin(Xs[np.delete(pop, j)], self.n_levels)
                col[i] = point_in_distances(Xs[i : i + 1], loo[None], weights)[0, 0]
        return ins, col

    def _consolidate(self, Xs, y_idx, members, labels, weights):
        """Greedy same-class merging, closest pairs first, that never adds a training error.

        Errors are counted leave-one-out (see ``_rule_column``): with plain resubstitution
        every sample sits inside its own rule and almost any merge looks harmless. Candidates
        are each rule's ``merge_neighbors`` nearest same-class rules (IN metric). Each
        sample's three nearest rules are tracked so that a trial costs one new column.
        """
        members = list(members)
        n_rules = len(members)
        rows = np.arange(len(Xs))
        columns = [self._rule_column(Xs, m, weights) for m in members]
        ins = np.stack([c[0] for c in columns])
        dist = np.stack([c[1] for c in columns], axis=1)
        top = _nearest3(dist)
        errors = int(np.sum(labels[top[:, 0]] != y_idx))

        rule_dist = in_distance_matrix(ins, weights)
        rule_dist[labels[:, None] != labels[None, :]] = np.inf
        np.fill_diagonal(rule_dist, np.inf)
        k = min(self.merge_neighbors, n_rules - 1)
        pairs = set()
        for a in range(n_rules):
            for b in np.argsort(rule_dist[a], kind="stable")[:k]:
                if np.isfinite(rule_dist[a, b]):
                    pairs.add((min(a, int(b)), max(a, int(b))))
        parent = list(range(n_rules))

        def find(i: int) -> int:
            while parent[i] != i:
                parent[i] = parent[parent[i]]
                i = parent[i]
            return i

        for a, b in sorted(pairs, key=lambda p: (rule_dist[p], p)):
            a, b = find(a), find(b)
            if a == b:
                continue
            pop = np.concatenate([members[a], members[b]])
            merged, col = self._rule_column(Xs, pop, weights)
            usable = (top != a) & (top != b)
            other = top[rows, usable.argmax(axis=1)]
            other_d = np.where(usable.any(axis=1), dist[rows, other], np.inf)
            pred = np.where(col < other_d, labels[a], labels[other])
            trial_errors = int(np.sum(pred != y_idx))
            if trial_errors <= errors:
                errors = trial_errors
                members[a], ins[a], members[b] = pop, merged, None
                dist[:, a], dist[:, b] = col, np.inf
                parent[b] = a
                stale = (~usable).any(axis=1) | (col < dist[rows, top[:, -1]])
                top[stale] = _nearest3(dist[stale])
        keep = [i for i in range(n_rules) if members[i] is not None]
        return [members[i] for i in keep], labels[keep], ins[keep]

    # -- prediction ----------------------------------------------------------------------

    def class_distances(self, X) -> np.ndarray:
        """Smallest IN distance from each sample to each class's rules: ``(n, n_classes)``."""
        check_is_fitted(self, "rule_ins_")
        X = validate_data(self, X, reset=False)
        d = point_in_distances(self._scale(X), self.rule_ins_, self.weights_)
        out = np.full((X.shape[0], len(self.classes_)), np.inf)
        for c in range(len(self.classes_)):
            cols = self.rule_labels_ == c
            if np.any(cols):
                out[:, c] = d[:, cols].min(axis=1)
        return out

    def predict(self, X) -> np.ndarray:
        """Class of the nearest rule (IN metric) for each sample."""
        check_is_fitted(self, "rule_ins_")
        return self.classes_[self.class_distances(X).argmin(axis=1)]
