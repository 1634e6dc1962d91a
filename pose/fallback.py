"""Answer a fallback estimator's pose when the main estimator is not confident.

A keypoint estimator is wrong with confidence where the evidence runs out (a small or mostly
covered object leaves a handful of matches): on the symmetric objects that the image-blind
constant answer gets right for free, such an answer scores *below* chance. A robot is better
served by the prior than by a wrong pose it believes. :class:`ConfidenceFallback` composes two
fitted estimators with the same contract: the main estimator's answer when it is valid with
``confidence >= min_confidence``, the fallback's otherwise (by default the image-blind
:class:`~pose.baselines.ChanceEstimator`; an appearance baseline such as ``pca-rbf`` also
works). It is a scikit-learn meta-estimator: ``set_params(estimator__keypoints__upscale=2)``
and ``GridSearchCV`` reach both parts, and the threshold is a swept parameter, not a flag.
"""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from sklearn.base import BaseEstimator, clone
from sklearn.utils.validation import check_is_fitted

from pose.composition import Composition, fit_estimator, load_part
from pose.symmetry import Symmetry
from pose.view import PoseEstimate, View, predict_each


def keeps_main(valid: bool, confidence: float, min_confidence: float) -> bool:
    """The gate: the main estimate stands when it is valid and confident enough."""
    return bool(valid) and confidence >= min_confidence


def _check_estimator(name: str, est) -> None:
    for method in ("fit", "predict", "to_arrays"):
        if not callable(getattr(est, method, None)):
            raise ValueError(
                f"{name} must be a pose estimator with fit/predict/to_arrays (a registered "
                f"one, e.g. make_estimator('chance')), got {est!r}"
            )


class ConfidenceFallback(Composition, BaseEstimator):
    """``estimator``'s pose, or ``fallback``'s where that is invalid or below
    ``min_confidence`` (``PoseEstimate.confidence``, in [0, 1]).

    ``None`` means the defaults: the pose-manifold estimator and the image-blind
    :class:`~pose.baselines.ChanceEstimator`. A fallen-back estimate says so in ``reason``
    (``"fallback: ..."``) and carries both estimators' timings.
    """

    def __init__(self, estimator=None, fallback=None, min_confidence: float = 0.2):
        self.estimator = estimator
        self.fallback = fallback
        self.min_confidence = min_confidence

    def _parts(self) -> tuple:
        from pose.baselines import ChanceEstimator
        from pose.manifold.estimator import PoseManifoldEstimator

        est = PoseManifoldEstimator() if self.estimator is None else self.estimator
        fb = ChanceEstimator() if self.fallback is None else self.fallback
        _check_estimator("estimator", est)
        _check_estimator("fallback", fb)
        c = self.min_confidence
        if isinstance(c, bool) or not isinstance(c, (int, float)) or not 0.0 <= c <= 1.0:
            raise ValueError(f"min_confidence must be in [0, 1], got {self.min_confidence!r}")
        return est, fb

    def fit(self, views: Sequence[View], poses, symmetry: Symmetry | None = None):
        """Fit fresh copies of both estimators on the same views and poses (``symmetry`` goes
        to the parts whose ``fit`` takes it, e.g. a
        :class:`~pose.selection.ValidationSelection`)."""
        est, fb = self._parts()
        views = list(views)
        self.estimator_ = fit_estimator(clone(est), views, poses, symmetry)
        self.fallback_ = fit_estimator(clone(fb), views, poses, symmetry)
        return self

    def predict(self, view: View | Sequence[View]) -> PoseEstimate | list[PoseEstimate]:
        check_is_fitted(self, "estimator_")
        return predict_each(self._predict_one, view)

    def _predict_one(self, view: View) -> PoseEstimate:
        t0 = time.perf_counter()
        main = self.estimator_.predict(view)
        if keeps_main(main.valid, main.confidence, self.min_confidence):
            return main
        t1 = time.perf_counter()
        back = self.fallback_.predict(view)
        why = (
            f"main estimate invalid ({main.reason})"
            if not main.valid
            else f"main confidence {main.confidence:.3f} < {self.min_confidence}"
        )
        timings = {f"main/{k}": v for k, v in main.timings_ms.items()}
        timings.update({f"fallback/{k}": v for k, v in back.timings_ms.items()})
        timings["main"] = (t1 - t0) * 1e3
        timings["total"] = (time.perf_counter() - t0) * 1e3
        reason = f"fallback: {why}" if back.valid else f"{why}; fallback invalid too: {back.reason}"
        return replace(
            back,
            timings_ms=timings,
            reason=reason,
            n_keypoints=main.n_keypoints,
            n_inliers=main.n_inliers,
        )

    # ---------------------------------------------------------------- files
    def to_arrays(self, prefix: str = "") -> dict[str, np.ndarray]:
        check_is_fitted(self, "estimator_")
        head = {
            "min_confidence": float(self.min_confidence),
            "estimator_class": type(self.estimator_).__name__,
            "fallback_class": type(self.fallback_).__name__,
        }
        out = {prefix + "fallback_params": np.array(json.dumps(head))}
        out.update(self.estimator_.to_arrays(prefix=prefix + "main/"))
        out.update(self.fallback_.to_arrays(prefix=prefix + "fallback/"))
        return out

    @classmethod
    def from_arrays(
        cls, arrays: dict[str, np.ndarray], prefix: str = "", format_version: int | None = None
    ) -> ConfidenceFallback:
        try:
            head = json.loads(str(arrays[prefix + "fallback_params"]))
            parts = [
                load_part(head[key], arrays, prefix + sub, format_version)
                for key, sub in (("estimator_class", "main/"), ("fallback_class", "fallback/"))
            ]
            est = cls(parts[0], parts[1], float(head["min_confidence"]))
        except (KeyError, TypeError, ValueError, json.JSONDecodeError) as exc:
            raise ValueError(f"fallback model file is missing or has bad entries ({exc})") from exc
        est.estimator_, est.fallback_ = parts
        return est
