"""Pick a headless OpenGL backend for MuJoCo before anything imports ``mujoco``.

MuJoCo reads ``MUJOCO_GL`` when its rendering context is first created. With no display and no
choice made by the user, GLFW cannot open a window, so we default to EGL, which works both on
NVIDIA drivers and on Mesa's software rasterizer (llvmpipe) on CPU-only Linux machines.

Two process-level choices follow from software rendering:

* dm_control (used only to build MJCF scenes) opens an EGL display when it is imported. That
  starts the rasterizer's threads in every process that merely imports scorbot-gym, and a
  ``fork`` of such a process inherits a display whose threads did not survive the fork.
  :func:`import_mjcf` imports it with its rendering disabled, so the display is opened by
  MuJoCo's own context on the first rendered frame, in the process that renders.
* llvmpipe rasterizes with one thread per core. A single env gains from that, but in a worker
  process of a vector env the processes already use every core: the rasterizer threads only
  contend with them, and the worker's own thread waits idle on its frame
  (``benchmarks/vector_env.py`` measures these). :func:`prepare_first_context` therefore asks
  llvmpipe to rasterize in the calling thread (``LP_NUM_THREADS=0``) in a child process
  (``multiprocessing.parent_process()`` is set) unless ``LP_NUM_THREADS`` is set; a main
  process keeps Mesa's default.

One library-level choice, too. Mesa's llvmpipe links the system's ``libLLVM`` and its loader opens
the driver with ``RTLD_GLOBAL``, so from the first frame on every LLVM symbol resolves to Mesa's
copy first. Triton (pulled in by the CUDA build of torch; ``torch._dynamo`` imports it when SB3
builds its Adam optimiser) bundles a different LLVM in ``libtriton.so`` and exports its symbols:
loaded after the first frame, it binds some 12,000 of them to Mesa's LLVM and segfaults in its
static initialisers. :func:`preload_bundled_llvm` loads such libraries before the first context,
privately (``RTLD_LOCAL``) and fully bound (``RTLD_NOW``), so that each copy keeps its own symbols.
"""

from __future__ import annotations

import ctypes
import functools
import importlib
import importlib.util
import multiprocessing
import os
import sys

VALID_BACKENDS = ("egl", "osmesa", "glfw")

# Extension libraries of Python packages that bundle their own LLVM with exported symbols:
# (package, path inside the package).
BUNDLED_LLVM_LIBRARIES = (("triton", "_C/libtriton.so"),)

INSTALL_HINT = (
    "No working OpenGL backend for MuJoCo rendering. On headless Linux install EGL, e.g. "
    "Debian/Ubuntu: `apt-get install libegl1 libgl1 libgles2` (Mesa's software EGL needs no GPU), "
    "then run with MUJOCO_GL=egl. With a display, MUJOCO_GL=glfw also works."
)


class RenderingUnavailableError(RuntimeError):
    """No OpenGL backend could create a MuJoCo rendering context."""


def choose_backend() -> str:
    """Set ``MUJOCO_GL`` if the user has not, and return the backend in use."""
    backend = os.environ.get("MUJOCO_GL", "").strip().lower()
    if backend:
        if backend not in VALID_BACKENDS and backend not in ("disable", "disabled", "off", "false"):
            raise RenderingUnavailableError(
                f"MUJOCO_GL={backend!r} is not a valid backend; valid: {', '.join(VALID_BACKENDS)}"
            )
        return backend
    has_display = bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    backend = "glfw" if (has_display or sys.platform == "darwin") else "egl"
    if sys.platform != "darwin":
        os.environ["MUJOCO_GL"] = backend
    return backend


def backend_in_use() -> str:
    return os.environ.get("MUJOCO_GL", "glfw" if sys.platform == "darwin" else "egl")


def import_mjcf():
    """Import ``dm_control.mjcf`` without letting dm_control open a rendering display."""
    if "dm_control.mjcf" in sys.modules:
        return sys.modules["dm_control.mjcf"]
    import mujoco  # noqa: F401  (MuJoCo's own renderer reads MUJOCO_GL here: keep the backend)

    saved = os.environ.get("MUJOCO_GL")
    os.environ["MUJOCO_GL"] = "disable"  # dm_control's renderer; scorbot-gym never uses it
    try:
        return importlib.import_module("dm_control.mjcf")
    finally:
        if saved is None:
            os.environ.pop("MUJOCO_GL", None)
        else:
            os.environ["MUJOCO_GL"] = saved


def prepare_first_context() -> None:
    """Settings read when the process opens its display (before the first GL context)."""
    if multiprocessing.parent_process() is not None:
        os.environ.setdefault("LP_NUM_THREADS", "0")
    preload_bundled_llvm()


@functools.cache
def preload_bundled_llvm() -> tuple[str, ...]:
    """Load the installed libraries of :data:`BUNDLED_LLVM_LIBRARIES` before Mesa's LLVM is.

    Returns the paths loaded. Nothing is imported (the package's ``__init__`` does not run); a
    library that is not installed, or that fails to load (its package's own import will then say
    why), is skipped. Once loaded here, the package's later import reuses the same handle.
    """
    if not sys.platform.startswith("linux"):
        return ()
    loaded = []
    for package, relative in BUNDLED_LLVM_LIBRARIES:
        try:
            spec = importlib.util.find_spec(package)
        except (ImportError, ValueError):
            continue
        if spec is None or not spec.submodule_search_locations:
            continue
        for folder in spec.submodule_search_locations:
            path = os.path.join(folder, relative)
            if os.path.isfile(path):
                try:
                    ctypes.CDLL(path, mode=os.RTLD_NOW | os.RTLD_LOCAL)
                except OSError:
                    continue
                loaded.append(path)
                break
    return tuple(loaded)
