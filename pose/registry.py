"""Pose estimators by name: ``make_estimator("manifold", bunches__n_bunches=6)``.

Every registered estimator follows the same contract — ``fit(views, poses)`` with
``camera_from_object`` poses ``(N, 4, 4)``, ``predict(view) -> PoseEstimate`` — so an ablation
is a swap of names (the CLI, the sweep runner and the pose sources all resolve them here).

A *spec* string names an estimator with parameters: ``name`` or ``name(param=value, ...)`` with
Python literal values, nested stage parameters (``bunches__n_bunches=4``, scikit-learn's
convention) set with ``set_params`` after construction. :func:`make_from_spec` builds one; the
``fallback`` composition takes its two parts as specs, ``select`` a tuple of candidate specs.
"""

from __future__ import annotations

import ast
import re
from collections.abc import Callable
from functools import partial
from typing import Any

from pose import baselines
from pose.manifold.estimator import PoseManifoldEstimator

_ESTIMATORS: dict[str, Callable[..., Any]] = {"manifold": PoseManifoldEstimator}
_ESTIMATORS["chance"] = baselines.ChanceEstimator
_ESTIMATORS["pca-nn"] = partial(baselines.PCAEstimator, regressor="nn")
_ESTIMATORS["pca-rbf"] = partial(baselines.PCAEstimator, regressor="rbf")
_ESTIMATORS["least-squares"] = baselines.LeastSquaresEstimator
_ESTIMATORS["part-based"] = baselines.PartBasedEstimator
_ESTIMATORS["n3m"] = baselines.N3MEstimator
_ESTIMATORS["sift-pnp"] = baselines.SiftPnPEstimator
_ESTIMATORS["nearest-view"] = baselines.NearestViewEstimator


_INVALID_PARAM = re.compile(
    r"Invalid parameter '([^']+)' for estimator (\w+)\(.*Valid parameters are: \[(.*)\]"
)
_SPEC = re.compile(r"^\s*([A-Za-z_][\w.\-]*)\s*(?:\((.*)\))?\s*$", re.DOTALL)


def parse_spec(text: str) -> tuple[str, dict[str, Any]]:
    """``"name(a=1, b__c='x')"`` -> ``("name", {"a": 1, "b__c": "x"})``; one-line
    ``ValueError`` saying what is wrong otherwise."""
    m = _SPEC.match(text) if isinstance(text, str) else None
    if not m:
        raise ValueError(
            f"bad estimator spec {text!r}; expected NAME or NAME(param=value, ...), "
            "e.g. manifold(refiner=None)"
        )
    name, args = m.group(1), (m.group(2) or "").strip()
    params: dict[str, Any] = {}
    if args:
        try:
            call = ast.parse(f"f({args})", mode="eval").body
            if not isinstance(call, ast.Call) or call.args:
                raise ValueError("positional arguments")
            for kw in call.keywords:
                if kw.arg is None:
                    raise ValueError("**kwargs")
                params[kw.arg] = ast.literal_eval(kw.value)
        except (SyntaxError, ValueError) as exc:
            raise ValueError(
                f"bad parameters in estimator spec {text!r} ({exc}); "
                "use keyword=literal pairs, e.g. manifold(refiner=None, matcher__min_inliers=6)"
            ) from exc
    return name, params


def make_with_params(name: str, params: dict[str, Any]) -> Any:
    """A new estimator: plain parameters go to the registered factory, nested ones
    (``stage__param``) through ``set_params`` afterwards."""
    try:
        est = make_estimator(name, **{k: v for k, v in params.items() if "__" not in k})
        nested = {k: v for k, v in params.items() if "__" in k}
        return est.set_params(**nested) if nested else est
    except AttributeError:  # set_params into a parameter that is a value, not a stage
        shallow = est.get_params(deep=False)
        bad = next(
            k for k in params
            if "__" in k and not hasattr(shallow.get(k.split("__")[0]), "set_params")
        )  # fmt: skip
        raise ValueError(
            f"estimator {name!r}: {bad!r} addresses a parameter of "
            f"{bad.split('__')[0]!r}, which is a value, not a stage with parameters"
        ) from None
    except TypeError as exc:  # a keyword the factory does not take
        m = re.search(r"unexpected keyword argument '([^']+)'", str(exc))
        if not m:
            raise
        valid = sorted(make_estimator(name).get_params(deep=False))  # the defaults build
        raise ValueError(
            f"estimator {name!r} has no parameter {m.group(1)!r}; valid: "
            + ", ".join(repr(v) for v in valid)
        ) from None
    except ValueError as exc:
        # scikit-learn's message carries the whole estimator's repr over many lines: say which
        # parameter is wrong and which ones are valid, on one line
        m = _INVALID_PARAM.search(" ".join(str(exc).split()))
        if not m:
            raise
        owner = m.group(2)  # the estimator itself, or the stage the nested name points into
        where = "" if owner == type(make_estimator(name)).__name__ else f" (in its {owner})"
        raise ValueError(
            f"estimator {name!r} has no parameter {m.group(1)!r}{where}; "
            f"valid: {m.group(3)} (a stage's own as stage__param)"
        ) from None


def make_from_spec(spec: str) -> Any:
    """A new, unfitted estimator from a spec string: ``"manifold-pnp(keypoints__upscale=2)"``."""
    return make_with_params(*parse_spec(spec))


def estimator_names() -> tuple[str, ...]:
    return tuple(sorted(_ESTIMATORS))


def register_estimator(name: str, factory: Callable[..., Any], *, overwrite: bool = False) -> None:
    """Make ``make_estimator(name, **params)`` call ``factory(**params)``."""
    if not name or not isinstance(name, str):
        raise ValueError(f"an estimator needs a non-empty name, got {name!r}")
    if name in _ESTIMATORS and not overwrite:
        raise ValueError(f"estimator {name!r} is already registered (pass overwrite=True)")
    if not callable(factory):
        raise TypeError(f"factory for estimator {name!r} must be callable, got {factory!r}")
    _ESTIMATORS[name] = factory


def make_estimator(name: str, **params: Any) -> Any:
    """A new, unfitted estimator of the registered kind ``name``."""
    if name not in _ESTIMATORS:
        raise ValueError(f"unknown estimator {name!r}; registered: {', '.join(estimator_names())}")
    return _ESTIMATORS[name](**params)


# The pose-manifold estimator and its stage-ablation variants (pose.manifold.variants): each a
# swap of one stage; extra parameters, nested ones too (bunches__n_bunches=6), via set_params.
def _register_manifold_variants() -> None:
    from functools import partial

    from pose.manifold.variants import VARIANTS, make_variant

    for name in VARIANTS:
        register_estimator(name, partial(make_variant, name), overwrite=name == "manifold")


_register_manifold_variants()


def _fallback(estimator: Any = "manifold", fallback: Any = "chance", min_confidence: float = 0.2):
    """``fallback(estimator='manifold-pnp(...)', fallback='chance', min_confidence=0.2)``:
    the parts are spec strings (or estimator objects)."""
    from pose.fallback import ConfidenceFallback

    def part(x: Any) -> Any:
        return make_from_spec(x) if isinstance(x, str) else x

    return ConfidenceFallback(part(estimator), part(fallback), min_confidence)


register_estimator("fallback", _fallback)


def _select(estimators: Any = (), cv: int = 4, random_state: int = 0):
    """``select(estimators=('manifold-pnp(...)', 'pca-rbf'), cv=4)``: the candidates are spec
    strings (named by them) or estimator objects."""
    from pose.selection import ValidationSelection

    if isinstance(estimators, (str, bytes)):
        raise ValueError(
            f"select needs a tuple of estimator specs, e.g. estimators=('sift-pnp', 'pca-rbf'), "
            f"got the single string {estimators!r}"
        )
    pairs = [(x, make_from_spec(x)) if isinstance(x, str) else x for x in estimators]
    return ValidationSelection(pairs, cv, random_state)


register_estimator("select", _select)
