"""Pickle-free save/load of a :class:`PoseManifoldEstimator` and its stage objects.

Stages are written as JSON ``{"__stage__": class name, "params": {...}}`` and rebuilt only from
the classes registered here (:func:`register_stage`), never by importing a name read from the
file. Fitted state is plain arrays; regressors bring theirs through ``to_arrays`` /
``load_arrays``. ``load`` checks that the arrays fit together and are finite, so a damaged file
fails at load with a message instead of later inside FLANN or with a NaN pose.

Format versions: 3 stores stage objects; 2 stored flat parameters (``n_bunches``,
``regressor="rbf"``, ``refine``...), which are translated to the equivalent stages on load.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np
from sklearn.base import BaseEstimator

from pose.features.keypoints import SiftKeypoints
from pose.features.matching import RansacMatcher
from pose.manifold.bunches import KMeansBunches
from pose.manifold.featurizer import ManifoldFeaturizer
from pose.manifold.reference import KeypointHeading, SilhouetteDirection
from pose.manifold.refinement import HomographyRefiner, PnPRefiner
from pose.manifold.regressors import NearestNeighbourRegressor, RBFNetwork, ScipyRBF
from pose.serialization import FORMAT_VERSION

RETRAIN = "re-train with `scorbot-gym pose train`"
_STAGES: dict[str, type] = {}
_FITTED = (
    "db_xy_",
    "db_desc_",
    "db_view_",
    "db_phi_",
    "view_R_allo_",
    "view_centre_",
    "view_size_",
    "view_z_eff_",
    "view_z_origin_",
)


def register_stage(cls: type) -> type:
    """Allow ``cls`` (a stage or regressor class) in model files; usable as a decorator."""
    if not (isinstance(cls, type) and issubclass(cls, BaseEstimator)):
        raise TypeError(f"a stage class must subclass sklearn's BaseEstimator, got {cls!r}")
    _STAGES[cls.__name__] = cls
    return cls


for _cls in (
    SiftKeypoints, RansacMatcher, KMeansBunches, KeypointHeading, SilhouetteDirection,
    ManifoldFeaturizer, HomographyRefiner, PnPRefiner, RBFNetwork, ScipyRBF,
    NearestNeighbourRegressor,
):  # fmt: skip
    register_stage(_cls)


def encode(value: Any, name: str = "params") -> Any:
    """JSON-able form of a parameter value (stages recursively)."""
    if isinstance(value, BaseEstimator):
        cls = type(value).__name__
        if _STAGES.get(cls) is not type(value):
            raise ValueError(
                f"{name}: {cls} is not a registered stage class, so it cannot be saved "
                "pickle-free; register it with pose.manifold.persistence.register_stage"
            )
        params = value.get_params(deep=False)
        return {
            "__stage__": cls,
            "params": {k: encode(v, f"{name}.{k}") for k, v in params.items()},
        }
    if isinstance(value, (tuple, list)):
        return [encode(v, name) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    raise ValueError(f"{name}: {type(value).__name__} values cannot be saved in a model file")


def decode(value: Any) -> Any:
    if isinstance(value, dict) and "__stage__" in value:
        cls = _STAGES.get(value["__stage__"])
        if cls is None:
            raise ValueError(f"unknown stage class {value['__stage__']!r} in the model file")
        return cls(**{k: decode(v) for k, v in value.get("params", {}).items()})
    if isinstance(value, list):
        return tuple(decode(v) for v in value)
    return value


def _v2_params(p: dict) -> dict:
    """Stage objects equivalent to the flat parameters of a version-2 file."""
    rbf = p.get("regressor", "rbf") == "rbf"
    blocks = (
        ("bunches",) + (("shape",) if p["use_shape"] else ()) + (("words",) if p["n_words"] else ())
    )
    return dict(
        keypoints=SiftKeypoints(p["contrast_threshold"], p["max_train_features"]),
        matcher=RansacMatcher(
            p["ratio"],
            p["ransac_method"],
            p["ransac_threshold"],
            p["min_inliers"],
            p["n_candidates"],
        ),  # fmt: skip
        bunches=KMeansBunches(p["n_bunches"], p["appearance_weight"], p["geometry_weight"]),
        reference=KeypointHeading() if p["reference"] == "keypoints" else SilhouetteDirection(),
        featurizer=ManifoldFeaturizer(
            blocks, "reference", p["n_words"] or 32, p["shape_weight"], p["words_weight"]
        ),
        regressor=RBFNetwork(
            p["n_centers"],
            p["width_scale"],
            p["ridge"],
            standardize=False,
            normalized=p["normalized_rbf"],
            random_state=p["random_state"],
        )
        if rbf
        else ScipyRBF(smoothing=p["ridge"], standardize=False),  # fmt: skip
        refiner=HomographyRefiner() if p["refine"] else None,
        translation_regressor=RBFNetwork(
            min(p["n_centers"], 32), alpha=p["ridge"], random_state=p["random_state"]
        ),
        augment_occlusion=tuple(p["augment_occlusion"]),
        allocentric=p["allocentric"],
        random_state=p["random_state"],
    )


def estimator_to_arrays(est, prefix: str = "") -> dict[str, np.ndarray]:
    from sklearn.utils.validation import check_is_fitted

    check_is_fitted(est, "regressor_")
    params = {k: encode(v, k) for k, v in est.get_params(deep=False).items()}
    out = {prefix + "params": np.array(json.dumps(params))}
    out[prefix + "x_mean_"] = est.featurizer_.x_mean_
    out[prefix + "x_scale_"] = est.featurizer_.x_scale_
    out[prefix + "words_"] = est.featurizer_.words_
    for k in _FITTED:
        v = getattr(est, k)
        out[prefix + k] = v  # full precision: a loaded model answers exactly as the fitted one
    if hasattr(est, "db_xyz_"):  # a refiner that lifts keypoints to 3-D (NaN: no depth)
        out[prefix + "db_xyz_"] = est.db_xyz_
    for tag, reg in (("rot", est.regressor_), ("trans", est.translation_regressor_)):
        if not callable(getattr(reg, "to_arrays", None)):
            raise ValueError(
                f"{type(reg).__name__} has no to_arrays()/load_arrays(), so a model using it "
                "cannot be saved pickle-free"
            )
        out.update({f"{prefix}{tag}/{k}": v for k, v in reg.to_arrays().items()})
    return out


def estimator_from_arrays(cls, arrays: dict, prefix: str = "", version: int | None = None):
    version = FORMAT_VERSION if version is None else version
    try:
        raw = json.loads(str(arrays[prefix + "params"]))
        params = _v2_params(raw) if version == 2 else {k: decode(v) for k, v in raw.items()}
        est = cls(**params)
        a = {k: np.asarray(arrays[prefix + k]) for k in (*_FITTED, "x_mean_", "x_scale_", "words_")}

        def sub(p: str) -> dict:
            return {k[len(p) :]: v for k, v in arrays.items() if k.startswith(p)}

        from pose.manifold.estimator import _seeded

        rot = _seeded(est.regressor, est.random_state).load_arrays(sub(prefix + "rot/"))
        trans = _seeded(est.translation_regressor, est.random_state)
        trans = trans.load_arrays(sub(prefix + "trans/"))
    except (KeyError, TypeError, AttributeError, json.JSONDecodeError) as exc:
        raise ValueError(f"model file is missing or has bad entries ({exc}); {RETRAIN}") from exc
    _check_arrays(a)
    xyz = arrays.get(prefix + "db_xyz_")
    if xyz is not None:
        xyz = np.asarray(xyz)
        if xyz.shape != (len(a["db_xy_"]), 3) or not np.issubdtype(xyz.dtype, np.floating):
            raise ValueError(
                f"inconsistent model file: db_xyz_ has shape {xyz.shape}, expected "
                f"({len(a['db_xy_'])}, 3) to match db_xy_; {RETRAIN}"
            )
        if np.isinf(xyz).any():
            raise ValueError(f"inconsistent model file: db_xyz_ holds infinite values; {RETRAIN}")
        est.db_xyz_ = xyz.astype(np.float32)
    elif getattr(est.refiner, "needs_depth", False):
        raise ValueError(
            f"model file has no db_xyz_, which its {type(est.refiner).__name__} needs; {RETRAIN}"
        )
    _check_widths(est, a)
    est.featurizer_ = _restored(est.featurizer, a)
    est.regressor_, est.translation_regressor_ = rot, trans
    est.db_xy_ = a["db_xy_"].astype(np.float32)
    est.db_desc_ = a["db_desc_"].astype(np.float32)
    est.db_view_ = a["db_view_"].astype(np.int64)
    est.db_phi_ = a["db_phi_"].astype(np.float32)
    for k in _FITTED[4:]:
        setattr(est, k, a[k].astype(float))
    est.n_train_views_ = len(est.view_R_allo_)
    est.n_features_in_ = len(a["x_mean_"])
    _check_regressors(est)
    est._build_index()
    return est


def _restored(featurizer: ManifoldFeaturizer, a: dict) -> ManifoldFeaturizer:
    from sklearn.base import clone

    try:
        return clone(featurizer).restore(a["words_"], a["x_mean_"], a["x_scale_"])
    except ValueError as exc:
        raise ValueError(f"inconsistent model file: {exc}; {RETRAIN}") from exc


def _check_widths(est, a: dict) -> None:
    """The parameters and the arrays agree on the feature layout."""
    f = est.featurizer
    want, got = f.n_columns(est.bunches.n_bunches), len(a["x_mean_"])
    n_words = len(a["words_"])
    if want != got or ("words" in f.blocks and n_words != f.n_words):
        raise ValueError(
            f"inconsistent model file: its parameters (blocks {tuple(f.blocks)}, "
            f"{est.bunches.n_bunches} bunches, {f.n_words} words) need {want} feature columns, "
            f"its arrays hold {got} with {n_words} words; {RETRAIN}"
        )


def _check_arrays(a: dict[str, np.ndarray]) -> None:
    """Shapes that fit together and finite values, or a ValueError saying what is wrong."""

    def bad(msg: str) -> ValueError:
        return ValueError(f"inconsistent model file: {msg}; {RETRAIN}")

    for k, v in a.items():
        if not np.issubdtype(v.dtype, np.number) or not np.isfinite(v).all():
            raise bad(f"{k} holds non-finite or non-numeric values")
    n = len(a["db_xy_"])
    if a["db_xy_"].shape != (n, 2) or n == 0:
        raise bad(f"db_xy_ has shape {a['db_xy_'].shape}, expected (N, 2)")
    for k, shape in (("db_desc_", (n, 128)), ("db_view_", (n,)), ("db_phi_", (n,))):
        if a[k].shape != shape:
            raise bad(f"{k} has shape {a[k].shape}, expected {shape} to match db_xy_")
    m = len(a["view_R_allo_"])
    if a["view_R_allo_"].shape != (m, 3, 3) or m == 0:
        raise bad(f"view_R_allo_ has shape {a['view_R_allo_'].shape}, expected (V, 3, 3)")
    for k, shape in (
        ("view_centre_", (m, 2)), ("view_size_", (m,)), ("view_z_eff_", (m,)),
        ("view_z_origin_", (m,)),
    ):  # fmt: skip
        if a[k].shape != shape:
            raise bad(f"{k} has shape {a[k].shape}, expected {shape} for {m} training views")
    views = a["db_view_"]
    if (views != np.round(views)).any() or views.min() < 0 or views.max() >= m:
        raise bad(f"db_view_ must hold view numbers 0..{m - 1}")
    if (np.diff(views) < 0).any():
        raise bad("db_view_ must be sorted by view")
    if a["words_"].ndim != 2 or a["words_"].shape[1] != 128:
        raise bad(f"words_ has shape {a['words_'].shape}, expected (n_words, 128)")
    d = a["x_mean_"].shape
    if len(d) != 1 or a["x_scale_"].shape != d or (a["x_scale_"] <= 0).any():
        raise bad("x_mean_ and x_scale_ must be equal-length vectors with x_scale_ > 0")
    if d[0] < len(a["words_"]) + 1:
        raise bad(f"{d[0]} feature columns cannot hold {len(a['words_'])} words and more")


def _check_regressors(est) -> None:
    """Both regressors answer a finite pose for a neutral input of the right width."""
    for name, reg, width, n_out in (
        ("rotation", est.regressor_, est.n_features_in_, 6),
        ("translation", est.translation_regressor_, 3, 3),
    ):
        try:
            y = np.asarray(reg.predict(np.zeros((1, width))))
        except Exception as exc:  # noqa: BLE001 - any failure means the arrays do not fit
            raise ValueError(
                f"inconsistent model file: the {name} regressor does not take {width} inputs "
                f"({type(exc).__name__}: {exc}); {RETRAIN}"
            ) from exc
        if y.shape != (1, n_out) or not np.isfinite(y).all():
            raise ValueError(
                f"inconsistent model file: the {name} regressor gives {y.shape} "
                f"{'non-finite ' if not np.isfinite(y).all() else ''}outputs, expected "
                f"(1, {n_out}) finite; {RETRAIN}"
            )
