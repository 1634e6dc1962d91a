"""Pickle-free model files: one ``.npz`` with a format tag and version, written atomically."""

from __future__ import annotations

import json
import os
import zipfile
from pathlib import Path

import numpy as np

from pose.fileio import atomic_savez

FORMAT = "scorbot-gym/pose-manifold"
FORMAT_VERSION = 3  # 2: keypoint canonical orientations and visual words; 3: stage objects
READABLE_VERSIONS = (2, 3)  # 2 is translated on load (flat parameters -> stage objects)
ZIP_MAGIC = (b"PK\x03\x04", b"PK\x05\x06")  # an .npz is a zip archive


def save_arrays(path: str | os.PathLike, arrays: dict[str, np.ndarray], meta: dict) -> Path:
    """Write ``arrays`` plus a JSON header to ``path`` via a temporary file and ``os.replace``."""
    header = {"format": FORMAT, "format_version": FORMAT_VERSION, **meta}
    return atomic_savez(path, __header__=np.array(json.dumps(header)), **arrays)


def load_arrays(path: str | os.PathLike) -> tuple[dict, dict[str, np.ndarray]]:
    """Header and arrays of a model file; ``ValueError`` naming the problem if it is not one."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no model file at {path}")
    with open(path, "rb") as f:
        magic = f.read(4)
    if magic not in ZIP_MAGIC:  # np.load would try to unpickle it and advise allow_pickle
        raise ValueError(
            f"{path} is not a scorbot-gym model file (not an .npz archive); "
            "write one with `scorbot-gym pose train`"
        )
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except (zipfile.BadZipFile, OSError, ValueError, EOFError, KeyError) as exc:
        raise ValueError(
            f"{path} is a corrupt model file (truncated or damaged .npz: {exc}); "
            "re-train with `scorbot-gym pose train`"
        ) from exc
    if "__header__" not in arrays:
        raise ValueError(f"{path} is an .npz file but not a scorbot-gym model file (no header)")
    try:
        header = json.loads(str(arrays.pop("__header__")))
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: corrupt model header ({exc})") from exc
    if not isinstance(header, dict):
        raise ValueError(f"{path}: corrupt model header (not a JSON object)")
    if header.get("format") != FORMAT:
        raise ValueError(f"{path}: format {header.get('format')!r}, expected {FORMAT!r}")
    if header.get("format_version") not in READABLE_VERSIONS:
        raise ValueError(
            f"{path}: model format version {header.get('format_version')!r} is not supported "
            f"(this code reads versions {READABLE_VERSIONS}); re-train with "
            "`scorbot-gym pose train`"
        )
    return header, arrays


def load_estimator_arrays(path: str | os.PathLike, class_name: str) -> tuple[dict, dict]:
    """``load_arrays(path)`` of a file that ``save`` of the estimator class ``class_name``
    wrote; a one-line ``ValueError`` naming what the file holds otherwise."""
    header, arrays = load_arrays(path)
    if header.get("kind") != "estimator" or header.get("class") != class_name:
        raise ValueError(
            f"{path} holds a {header.get('class', header.get('kind'))!r}, not a {class_name}"
        )
    return header, arrays
