"""Loaders for public silhouette datasets: MPEG-7 CE-Shape-1 and ETH-80.

Layouts understood
------------------
* ``mpeg7``: one flat folder of ``<class>-<n>.gif`` (CE-Shape-1: 70 classes x 20, e.g.
  ``apple-1.gif``, ``Bone-12.gif``); ``.png`` / ``.bmp`` with the same naming are accepted.
  Group = the file (every image is its own group).
* ``eth80``: ``<category>/<category><instance>/maps/*.png`` silhouette maps (ETH-80 with
  segmentation maps, e.g. ``cup/cup3/maps/cup3-090-180-map.png``) or, when an instance folder
  has no ``maps/``, the cropped-close layout ``<category>/<instance>/*.png``. Group = the
  instance folder, so that splits can hold out whole physical objects.

Images are read with Pillow (OpenCV cannot read GIF reliably), converted to grey and
binarised with foreground = bright: a two-level image keeps its nonzero pixels, anything else
is thresholded with Otsu. Unreadable or empty images raise ``ValueError`` naming the file.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from PIL import Image, UnidentifiedImageError

from pose.shape.descriptors import MIN_PIXELS

LAYOUTS = ("mpeg7", "eth80")
_MPEG7_NAME = re.compile(r"^(?P<cls>.+)-(?P<num>\d+)\.(gif|png|bmp)$", re.IGNORECASE)
_IMAGE_SUFFIXES = (".png", ".gif", ".bmp")


@dataclass
class SilhouetteSet:
    """Binary silhouettes with their class labels, groups (for grouped splits) and sources.

    ``extras`` holds optional per-silhouette arrays (e.g. ``"metric_size"`` of rendered sets).
    """

    masks: list[np.ndarray]
    labels: np.ndarray
    groups: np.ndarray
    sources: list[str] = field(default_factory=list)
    extras: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = len(self.masks)
        if len(self.labels) != n or len(self.groups) != n:
            raise ValueError(
                f"masks, labels and groups must have equal length, got "
                f"{n}, {len(self.labels)}, {len(self.groups)}"
            )
        for key, values in self.extras.items():
            if len(values) != n:
                raise ValueError(f"extras[{key!r}] has {len(values)} entries for {n} masks")

    def __len__(self) -> int:
        return len(self.masks)

    @property
    def classes(self) -> list[str]:
        return sorted({str(c) for c in self.labels})


def read_silhouette(path: str | Path, max_side: int | None = 256) -> np.ndarray:
    """Read one image file as a bool mask (foreground = bright), optionally downscaled.

    ``max_side`` caps the longer image side (area interpolation, then > 0.5), which keeps
    descriptor cost bounded for large scans; None keeps full resolution.
    """
    path = Path(path)
    try:
        with Image.open(path) as img:
            img.seek(0)  # first frame of a GIF
            grey = np.asarray(img.convert("L"), dtype=np.uint8)
    except (OSError, UnidentifiedImageError, ValueError) as exc:
        raise ValueError(f"cannot read image {path}: {exc}") from exc
    values = np.unique(grey)
    if len(values) <= 2:
        mask = grey > values[0] if len(values) == 2 else np.zeros_like(grey, dtype=bool)
    else:
        _, binary = cv2.threshold(grey, 0, 1, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
        mask = binary.astype(bool)
    if max_side is not None and max(mask.shape) > max_side:
        s = max_side / max(mask.shape)
        size = (max(1, round(mask.shape[1] * s)), max(1, round(mask.shape[0] * s)))
        mask = cv2.resize(mask.astype(np.float32), size, interpolation=cv2.INTER_AREA) > 0.5
    if int(mask.sum()) < MIN_PIXELS:
        raise ValueError(
            f"image {path} has an empty silhouette (fewer than {MIN_PIXELS} foreground "
            "pixels; silhouettes must be bright objects on a dark background)"
        )
    return mask


def load_mpeg7(root: str | Path, max_side: int | None = 256) -> SilhouetteSet:
    """Load a flat MPEG-7 CE-Shape-1 folder of ``<class>-<n>.gif`` files."""
    root = _existing_dir(root)
    files = sorted(p for p in root.iterdir() if p.is_file() and _MPEG7_NAME.match(p.name))
    if not files:
        raise ValueError(f"no MPEG-7 files named '<class>-<n>.gif' (or .png/.bmp) found in {root}")
    labels = [_MPEG7_NAME.match(p.name)["cls"] for p in files]
    masks = [read_silhouette(p, max_side) for p in files]
    return SilhouetteSet(
        masks, np.array(labels), np.array([p.stem for p in files]), [str(p) for p in files]
    )


def load_eth80(root: str | Path, max_side: int | None = 256) -> SilhouetteSet:
    """Load ETH-80: ``<category>/<instance>/maps/*.png``, else ``<category>/<instance>/*.png``."""
    root = _existing_dir(root)
    masks, labels, groups, sources = [], [], [], []
    for category in sorted(p for p in root.iterdir() if p.is_dir()):
        for instance in sorted(p for p in category.iterdir() if p.is_dir()):
            folder = instance / "maps" if (instance / "maps").is_dir() else instance
            for f in sorted(folder.iterdir()):
                if f.is_file() and f.suffix.lower() in _IMAGE_SUFFIXES:
                    masks.append(read_silhouette(f, max_side))
                    labels.append(category.name)
                    groups.append(f"{category.name}/{instance.name}")
                    sources.append(str(f))
    if not masks:
        raise ValueError(
            f"no ETH-80 images found under {root}: expected "
            "<category>/<instance>/maps/*.png or <category>/<instance>/*.png"
        )
    return SilhouetteSet(masks, np.array(labels), np.array(groups), sources)


def detect_layout(root: str | Path) -> str:
    """``"mpeg7"`` if ``root`` holds ``<class>-<n>.gif`` files, ``"eth80"`` if it holds
    ``<category>/<instance>/`` folders of images; otherwise ``ValueError``."""
    root = _existing_dir(root)
    if any(p.is_file() and _MPEG7_NAME.match(p.name) for p in root.iterdir()):
        return "mpeg7"
    for category in (p for p in root.iterdir() if p.is_dir()):
        for instance in (p for p in category.iterdir() if p.is_dir()):
            folder = instance / "maps" if (instance / "maps").is_dir() else instance
            if any(f.suffix.lower() in _IMAGE_SUFFIXES for f in folder.iterdir()):
                return "eth80"
    raise ValueError(
        f"cannot tell the layout of {root}: expected MPEG-7 '<class>-<n>.gif' files or "
        "ETH-80 '<category>/<instance>/[maps/]*.png' folders"
    )


def load_dataset(root: str | Path, layout: str = "auto", max_side: int | None = 256):
    """Load ``root`` in the given layout (``"auto"``, ``"mpeg7"`` or ``"eth80"``)."""
    if layout == "auto":
        layout = detect_layout(root)
    if layout == "mpeg7":
        return load_mpeg7(root, max_side)
    if layout == "eth80":
        return load_eth80(root, max_side)
    raise ValueError(f"unknown layout {layout!r}; valid: 'auto', {', '.join(map(repr, LAYOUTS))}")


def _existing_dir(root: str | Path) -> Path:
    root = Path(root)
    if not root.is_dir():
        raise FileNotFoundError(f"dataset folder {root} does not exist or is not a folder")
    return root
