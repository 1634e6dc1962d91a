"""Choose, per object, the candidate estimator that does best on held-out training views.

No single estimator is best on every object: on small, axially symmetric objects (a ball, a
can) an appearance baseline finds the resting face from the silhouette, where a keypoint
estimator has too few keypoints and answers a wrong tilt with confidence; on textured or
asymmetric objects PnP on keypoints is far more precise. Which composition of the keypoint
estimator fits best also depends on the object's poses: a resting object is best answered by a
training view's exact tilt, a leaning one by PnP. :class:`ValidationSelection` makes that choice
the way a practitioner would, from the training data alone: k-fold cross-validation of every
candidate on the training views (symmetry-aware success@5°, the median error breaking ties),
then the winner refitted on all views. It is scikit-learn's model selection applied per object
(one fitted selection per object model), not a change of any candidate.

The image-blind ``chance`` answer (the training medoid) belongs among the candidates as model
selection's null model. Where every training pose of an object is one pose up to its symmetry
(a can or a ball standing upright) it is right on every view and exact, so it wins the tie on
the median error, and it stays right under any occlusion or camera change, where an image-based
answer degrades; where the poses differ, it loses the validation and is never chosen.
"""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Sequence

import numpy as np
from sklearn.base import BaseEstimator, clone
from sklearn.utils.validation import check_is_fitted

from pose.baselines._common import check_training_set
from pose.composition import Composition, fit_estimator, load_part
from pose.features.keypoints import shared_keypoints
from pose.metrics import rotation_error_deg, success_rate
from pose.symmetry import Symmetry
from pose.view import PoseEstimate, View, predict_each


def _named(estimators) -> list[tuple[str, object]]:
    """``estimators`` as ``(name, estimator)`` pairs with unique names."""
    if isinstance(estimators, (str, bytes)) or not isinstance(estimators, Sequence):
        raise ValueError(
            f"estimators must be a non-empty sequence of estimators or (name, estimator) pairs, "
            f"got {estimators!r}"
        )
    given, ests = [], []
    for i, item in enumerate(estimators):
        name, est = item if isinstance(item, tuple) and len(item) == 2 else (None, item)
        for method in ("fit", "predict", "to_arrays"):
            if not callable(getattr(est, method, None)):
                raise ValueError(
                    f"estimators[{i}] must be a pose estimator with fit/predict/to_arrays (e.g. "
                    f"make_estimator('pca-rbf')), got {est!r}"
                )
        given.append(None if name is None else str(name))
        ests.append(est)
    if not ests:
        raise ValueError("estimators must hold at least one candidate, got none")
    # bare estimators are named by class, numbered where a class repeats (as scikit-learn's
    # make_pipeline does), so the scores and fit errors of each stay apart
    bare = [type(e).__name__ for n, e in zip(given, ests, strict=True) if n is None]
    seen: Counter = Counter()
    names = []
    for n, e in zip(given, ests, strict=True):
        if n is None:
            n = type(e).__name__
            if bare.count(n) > 1:
                seen[n] += 1
                n = f"{n}-{seen[n]}"
        names.append(n)
    repeated = sorted(n for n, c in Counter(names).items() if c > 1)
    if repeated:
        raise ValueError(f"candidate names must be unique, got {repeated[0]!r} more than once")
    return list(zip(names, ests, strict=True))


class ValidationSelection(Composition, BaseEstimator):
    """The candidate of ``estimators`` with the highest cross-validated success@5° on the
    training views, refitted on all of them.

    ``estimators``: estimators or ``(name, estimator)`` pairs, earlier ones winning exact ties.
    ``cv``: the number of folds (a seeded random partition of the views, ``random_state``):
    each candidate is fitted ``cv`` times, each time on all folds but one, and answers the
    views of that fold, so every training view is scored once. ``fit(views, poses,
    symmetry=None)`` scores with the object's symmetry when given (without it a can's arbitrary
    heading counts as an error). A candidate whose ``fit`` rejects a reduced training set
    (``ValueError``, e.g. too few keypoints) is passed over. After ``fit``: ``best_index_`` and
    ``best_name_`` (into ``candidate_names_``), ``best_estimator_``, and per candidate
    ``validation_success_`` and ``validation_median_deg_`` (NaN where it could not be fitted).
    """

    def __init__(self, estimators=(), cv: int = 4, random_state: int = 0):
        self.estimators = estimators
        self.cv = cv
        self.random_state = random_state

    def _check_params(self) -> list[tuple[str, object]]:
        for name in ("cv", "random_state"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
                raise ValueError(f"{name} must be an integer, got {v!r}")
        if self.cv < 2:
            raise ValueError(f"cv must be at least 2 folds, got {self.cv}")
        return _named(self.estimators)

    def _validate(self, est, views: list[View], P: np.ndarray, folds, symmetry) -> np.ndarray:
        """Each view's symmetry-aware rotation error, answered by ``est`` fitted on the other
        folds (NaN for an invalid answer); ``ValueError`` if a fit is refused."""
        errs = np.full(len(views), np.nan)
        for fold in folds:
            rest = np.setdiff1d(np.arange(len(views)), fold)
            model = fit_estimator(clone(est), [views[i] for i in rest], P[rest], symmetry)
            answers = predict_each(model.predict, [views[i] for i in fold])
            for e, i in zip(answers, fold, strict=True):
                if e.valid:
                    errs[i] = rotation_error_deg(e.rotation, P[i, :3, :3], symmetry)
        return errs

    def fit(self, views: Sequence[View], poses, symmetry: Symmetry | None = None):
        with shared_keypoints():  # every fold's candidates see the same views' SIFT
            return self._fit(views, poses, symmetry)

    def _fit(self, views: Sequence[View], poses, symmetry: Symmetry | None):
        pairs = self._check_params()
        views, P = check_training_set(views, poses)
        if len(pairs) > 1 and len(views) < self.cv:
            raise ValueError(
                f"cv={self.cv} folds need at least {self.cv} training views, got {len(views)}"
            )
        success = np.full(len(pairs), np.nan)
        median = np.full(len(pairs), np.nan)
        self.fit_errors_: dict[str, str] = {}
        if len(pairs) > 1:
            order = np.random.default_rng(self.random_state).permutation(len(views))
            folds = np.array_split(order, self.cv)
            for k, (name, est) in enumerate(pairs):
                try:
                    errs = self._validate(est, views, P, folds, symmetry)
                except ValueError as exc:  # the candidate's "cannot fit these views"
                    self.fit_errors_[name] = str(exc)
                    continue
                success[k] = success_rate(errs, 5.0)
                finite = errs[np.isfinite(errs)]
                median[k] = float(np.median(finite)) if finite.size else np.inf
            if np.isnan(success).all():
                raise ValueError(
                    "no candidate could be fitted on these views: "
                    + "; ".join(f"{k}: {v}" for k, v in self.fit_errors_.items())
                )
        # best success, then the smaller median error, then the earlier candidate
        keys = [
            (-np.nan_to_num(s, nan=-1.0), np.nan_to_num(m, nan=np.inf), k)
            for k, (s, m) in enumerate(zip(success, median, strict=True))
        ]
        self.best_index_ = int(min(keys)[2])
        self.best_name_ = pairs[self.best_index_][0]
        self.best_estimator_ = fit_estimator(clone(pairs[self.best_index_][1]), views, P, symmetry)
        self.candidate_names_ = [name for name, _ in pairs]
        self.validation_success_ = success
        self.validation_median_deg_ = median
        return self

    def predict(self, view: View | Sequence[View]) -> PoseEstimate | list[PoseEstimate]:
        """The selected candidate's estimate (a list for a sequence of views)."""
        check_is_fitted(self, "best_estimator_")
        return predict_each(self.best_estimator_.predict, view)

    # ---------------------------------------------------------------- files
    def to_arrays(self, prefix: str = "") -> dict[str, np.ndarray]:
        check_is_fitted(self, "best_estimator_")
        head = {
            "cv": int(self.cv),
            "random_state": int(self.random_state),
            "best_index": self.best_index_,
            "candidate_names": self.candidate_names_,
            "validation_success": [
                None if np.isnan(s) else float(s) for s in self.validation_success_
            ],  # fmt: skip
            "validation_median_deg": [
                None if np.isnan(m) else float(m) for m in self.validation_median_deg_
            ],  # fmt: skip
            "fit_errors": self.fit_errors_,
            "selected_class": type(self.best_estimator_).__name__,
        }
        out = {prefix + "selection_params": np.array(json.dumps(head))}
        out.update(self.best_estimator_.to_arrays(prefix=prefix + "selected/"))
        return out

    @classmethod
    def from_arrays(
        cls, arrays: dict[str, np.ndarray], prefix: str = "", format_version: int | None = None
    ) -> ValidationSelection:
        """The selection as fitted; its ``estimators`` is the selected estimator alone (the
        other candidates were never refitted), the names and scores say what it was chosen from."""
        try:
            head = json.loads(str(arrays[prefix + "selection_params"]))
            best = load_part(head["selected_class"], arrays, prefix + "selected/", format_version)
            names = [str(n) for n in head["candidate_names"]]
            index = int(head["best_index"])
            est = cls([(names[index], best)], int(head["cv"]),
                      int(head["random_state"]))  # fmt: skip
            est.best_index_, est.best_name_, est.best_estimator_ = index, names[index], best
            est.candidate_names_ = names
            est.validation_success_ = np.array(head["validation_success"], float)
            est.validation_median_deg_ = np.array(head["validation_median_deg"], float)
            est.fit_errors_ = dict(head["fit_errors"])
        except (KeyError, TypeError, ValueError, IndexError, json.JSONDecodeError) as exc:
            raise ValueError(f"selection model file is missing or has bad entries ({exc})") from exc
        return est
