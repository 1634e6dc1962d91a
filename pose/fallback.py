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
import os
import time
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from sklearn.base import BaseEstimator, clone
from sklearn.utils.validation import check_is_fitted

from pose.baselines._common import check_training_set
from pose.metrics import rotation_error_deg, success_rate
from pose.serialization import load_arrays, save_arrays
from pose.symmetry import Symmetry
from pose.view import PoseEstimate, View


def _loadable_classes() -> dict[str, type]:
    """Estimator classes a fallback file may hold, by class name."""
    from pose import baselines
    from pose.manifold.estimator import PoseManifoldEstimator

    classes = [PoseManifoldEstimator, ConfidenceFallback]
    classes += [getattr(baselines, name) for name in baselines.__all__]
    return {c.__name__: c for c in classes}


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


class ConfidenceFallback(BaseEstimator):
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

    def fit(self, views: Sequence[View], poses) -> ConfidenceFallback:
        """Fit fresh copies of both estimators on the same views and poses."""
        est, fb = self._parts()
        views = list(views)
        self.estimator_ = clone(est).fit(views, poses)
        self.fallback_ = clone(fb).fit(views, poses)
        return self

    def predict(self, view: View | Sequence[View]) -> PoseEstimate | list[PoseEstimate]:
        check_is_fitted(self, "estimator_")
        if isinstance(view, View):
            return self._predict_one(view)
        if isinstance(view, (str, bytes)) or not isinstance(view, Sequence):
            raise ValueError(
                f"predict expects a pose.view.View or a sequence of them, got {type(view).__name__}"
            )
        return [self._predict_one(v) for v in view]

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

    def score(self, views: Sequence[View], poses, symmetry: Symmetry | None = None) -> float:
        """Share of ``views`` within 5 degrees of ``poses`` (invalid answers fail)."""
        views, P = check_training_set(views, poses)
        errs = [
            rotation_error_deg(e.rotation, p[:3, :3], symmetry) if e.valid else np.nan
            for e, p in zip(self.predict(views), P, strict=True)
        ]
        return success_rate(errs, 5.0)

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
        classes = _loadable_classes()
        try:
            head = json.loads(str(arrays[prefix + "fallback_params"]))
            parts = []
            for key, sub in (("estimator_class", "main/"), ("fallback_class", "fallback/")):
                part_cls = classes[head[key]]
                if part_cls.__name__ in ("PoseManifoldEstimator", "ConfidenceFallback"):
                    parts.append(part_cls.from_arrays(arrays, prefix + sub, format_version))
                else:
                    parts.append(part_cls.from_arrays(arrays, prefix + sub))
            est = cls(parts[0], parts[1], float(head["min_confidence"]))
        except (KeyError, TypeError, ValueError, json.JSONDecodeError) as exc:
            raise ValueError(f"fallback model file is missing or has bad entries ({exc})") from exc
        est.estimator_, est.fallback_ = parts
        return est

    def save(self, path: str | os.PathLike) -> None:
        """Both fitted estimators in one ``.npz`` (atomic, pickle-free, versioned)."""
        save_arrays(path, self.to_arrays(), {"kind": "estimator", "class": type(self).__name__})

    @classmethod
    def load(cls, path: str | os.PathLike) -> ConfidenceFallback:
        header, arrays = load_arrays(path)
        if header.get("kind") != "estimator" or header.get("class") != cls.__name__:
            raise ValueError(
                f"{path} holds a {header.get('class', header.get('kind'))!r}, not a {cls.__name__}"
            )
        return cls.from_arrays(arrays, format_version=header["format_version"])
