"""Held-out comparison of FLR, k-NN and SVM on shape descriptors; JSON and confusion PNG.

Each classifier gets a small hyperparameter grid search (stratified 3-fold CV on the training
part only): its own main parameter, and the same ART block weight options for all three
(the ART block is the most discriminative; weighting it is tuned, not assumed). The test part
is touched once, by the refitted best model.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from sklearn.metrics import confusion_matrix
from sklearn.model_selection import (
    GridSearchCV,
    StratifiedGroupKFold,
    StratifiedKFold,
    train_test_split,
)

from pose.fileio import atomic_write
from pose.shape.baselines import make_classifiers
from pose.shape.descriptors import DESCRIPTOR_LENGTH, block_weights

PARAM_GRIDS = {
    "flr": {"vigilance": [0.95, 0.97, 1.0]},
    "knn": {"kneighborsclassifier__n_neighbors": [1, 3, 5]},
    "svm": {"svc__C": [1.0, 10.0, 100.0]},
}
WEIGHT_PARAM = {"flr": "feature_weights", "knn": "featureweights__weights",
                "svm": "featureweights__weights"}  # fmt: skip
ART_WEIGHTS = (1.0, 2.0, 3.0)


def _grid(name: str, n_features: int) -> tuple[dict, list[tuple[float, object]]]:
    """The grid of classifier ``name``; block weights only when X is a shape descriptor."""
    grid = dict(PARAM_GRIDS[name])
    options: list[tuple[float, object]] = []
    if n_features >= DESCRIPTOR_LENGTH:
        extra = n_features - DESCRIPTOR_LENGTH
        options = [(a, None if a == 1.0 else block_weights(art=a, n_extra=extra))
                   for a in ART_WEIGHTS]  # fmt: skip
        grid[WEIGHT_PARAM[name]] = [w for _, w in options]
    return grid, options


def _readable(best: dict, options: list[tuple[float, object]]) -> dict:
    """Best parameters for JSON: short names, weight vectors as their ART weight."""
    out = {}
    for key, value in best.items():
        if key in WEIGHT_PARAM.values():
            out["art_weight"] = next(
                a for a, w in options if (w is None) == (value is None) and np.array_equal(w, value)
            )
        else:
            out[key.split("__")[-1]] = value
    return out


def split_indices(
    labels: np.ndarray, groups: np.ndarray | None, test_size: float, seed: int
) -> tuple[np.ndarray, np.ndarray]:
    """Train/test indices: stratified random, or whole groups held out when ``groups`` given."""
    if not 0.0 < test_size < 1.0:
        raise ValueError(f"test_size must be in (0, 1), got {test_size}")
    idx = np.arange(len(labels))
    counts = np.unique(labels, return_counts=True)[1]
    if counts.min() < 2:
        raise ValueError("every class needs at least 2 silhouettes to be split into train/test")
    if groups is None:
        return train_test_split(idx, test_size=test_size, random_state=seed, stratify=labels)
    n_splits = max(2, round(1.0 / test_size))
    folds = StratifiedGroupKFold(n_splits=n_splits, shuffle=True, random_state=seed)
    train, test = next(folds.split(idx, labels, groups))
    return train, test


def evaluate(
    X: np.ndarray,
    y: np.ndarray,
    seed: int = 0,
    test_size: float = 0.5,
    groups: np.ndarray | None = None,
    tune: bool = True,
    split: tuple[np.ndarray, np.ndarray] | None = None,
    report_groups: np.ndarray | None = None,
) -> dict:
    """Fit FLR, k-NN and SVM on a training split of ``(X, y)``; report held-out accuracy.

    ``split`` (train indices, test indices) overrides the split made from ``test_size``,
    ``groups`` and ``seed``, e.g. to test on silhouettes from other cameras.
    ``report_groups`` (one name per sample) adds each classifier's test accuracy per group.

    Returns a JSON-ready dict: per classifier ``accuracy``, ``best_params``, ``fit_s``,
    ``predict_ms_per_sample`` and ``confusion`` (rows = true class, columns = predicted, in
    ``classes`` order), plus split sizes.
    """
    X = np.asarray(X, dtype=np.float64)
    y = np.asarray(y)
    if X.ndim != 2 or len(X) != len(y):
        raise ValueError(f"X must be (n, d) with one label per row, got {X.shape} and {y.shape}")
    if split is None:
        train, test = split_indices(y, groups, test_size, seed)
        how = "grouped" if groups is not None else "stratified random"
    else:
        train, test = (np.asarray(s, dtype=int) for s in split)
        how = "given"
    classes = sorted({str(c) for c in y})
    y = y.astype(str)
    out: dict = {
        "n_train": int(len(train)),
        "n_test": int(len(test)),
        "n_features": int(X.shape[1]),
        "classes": classes,
        "seed": seed,
        "split": how,
        "classifiers": {},
    }
    cv = StratifiedKFold(3, shuffle=True, random_state=seed)
    for name, clf in make_classifiers(seed).items():
        t0 = time.perf_counter()
        min_class = np.unique(y[train], return_counts=True)[1].min()
        if tune and min_class >= 3:
            grid, options = _grid(name, X.shape[1])
            search = GridSearchCV(clf, grid, cv=cv, n_jobs=1).fit(X[train], y[train])
            model, best = search.best_estimator_, _readable(search.best_params_, options)
        else:
            model, best = clf.fit(X[train], y[train]), {}
        fit_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        pred = model.predict(X[test])
        predict_ms = 1000.0 * (time.perf_counter() - t0) / len(test)
        entry = {
            "accuracy": float(np.mean(pred == y[test])),
            "best_params": best,
            "fit_s": round(fit_s, 3),
            "predict_ms_per_sample": round(predict_ms, 4),
            "confusion": confusion_matrix(y[test], pred, labels=classes).tolist(),
        }
        if report_groups is not None:
            g = np.asarray(report_groups).astype(str)[test]
            entry["accuracy_per_group"] = {
                k: float(np.mean(pred[g == k] == y[test][g == k])) for k in sorted(set(g))
            }
        if name == "flr":
            entry["n_rules"] = int(len(model.rule_labels_))
        out["classifiers"][name] = entry
    accs = {k: v["accuracy"] for k, v in out["classifiers"].items()}
    out["best_baseline"] = max(("knn", "svm"), key=accs.get)
    gap = 100 * (accs["flr"] - accs[out["best_baseline"]])
    out["flr_minus_best_baseline_points"] = round(gap, 2)
    return out


def plot_confusions(result: dict, path: str | Path, title: str = "") -> None:
    """One confusion-matrix panel per classifier (row-normalised colours, counts printed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    classes = result["classes"]
    names = list(result["classifiers"])
    n = len(classes)
    side = max(4.0, 0.45 * n + 2.0)
    fig, axes = plt.subplots(1, len(names), figsize=(side * len(names), side + 0.6))
    for ax, name in zip(np.atleast_1d(axes), names, strict=True):
        cm = np.array(result["classifiers"][name]["confusion"], dtype=float)
        norm = cm / np.maximum(cm.sum(axis=1, keepdims=True), 1)
        ax.imshow(norm, cmap="Blues", vmin=0, vmax=1)
        for i in range(n):
            for j in range(n):
                if cm[i, j]:
                    colour = "white" if norm[i, j] > 0.5 else "black"
                    ax.text(j, i, int(cm[i, j]), ha="center", va="center", fontsize=7, color=colour)
        ax.set_xticks(range(n), classes, rotation=90, fontsize=7)
        ax.set_yticks(range(n), classes, fontsize=7)
        ax.set_xlabel("predicted")
        ax.set_ylabel("true")
        acc = result["classifiers"][name]["accuracy"]
        ax.set_title(f"{name.upper()}  accuracy {100 * acc:.1f} %")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    try:
        atomic_write(path, lambda f: fig.savefig(f, dpi=110, format="png"))
    finally:
        plt.close(fig)
