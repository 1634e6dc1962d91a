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

A third, library-level choice. Mesa's llvmpipe links the system's ``libLLVM`` and its loader opens
the driver with ``RTLD_GLOBAL``, so from the first frame on every LLVM symbol resolves to Mesa's
copy first. Triton (pulled in by the CUDA build of torch; ``torch._dynamo`` imports it when SB3
builds its Adam optimiser) bundles a different LLVM in ``libtriton.so`` and exports its symbols:
loaded after the first frame, it binds some 12,000 of them to Mesa's LLVM and segfaults in its
static initialisers. :func:`preload_bundled_llvm` loads such libraries before the first context,
privately (``RTLD_LOCAL``) and fully bound (``RTLD_NOW``), so that each copy keeps its own symbols.

A fourth follows from ``fork``: Mesa's EGL display keeps rasterizer threads and locks that a
forked child inherits without the threads, so a child whose parent had rendered deadlocks on its
first frame (``gymnasium.vector.AsyncVectorEnv`` forks by default on Linux). Every object that
opens a GL context registers here (:func:`track_gl_owner`); just before this process forks,
:func:`release_gl_before_fork` frees their contexts and terminates MuJoCo's EGL display, so
the child opens a display of its own, and the owners rebuild their contexts lazily on their
next frame (one context build, ~0.3 s in software GL). A ``mujoco.Renderer`` of your own in a
process that forks after rendering is not ours to free: make it after the fork, or start
workers with ``context="spawn"``.
"""

from __future__ import annotations

import ctypes
import functools
import importlib
import importlib.util
import multiprocessing
import os
import sys
import weakref
from typing import Protocol

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


class GLOwner(Protocol):
    def release_gl(self) -> None:
        """Free every GL context held; the next frame builds them again."""


_OWNERS: weakref.WeakSet = weakref.WeakSet()
_rendered = False  # a GL context of ours was opened in this process (its display may be open)
#: set in a forked child whose parent still had an EGL display open at the fork
_FORKED_WITH_DISPLAY = False

FORK_HINT = (
    "this process was forked from one that had an OpenGL display open, and a forked child "
    "cannot render with it; start the workers with context='spawn' (e.g. "
    "gymnasium.vector.AsyncVectorEnv(env_fns, context='spawn'))"
)


def prepare_first_context() -> None:
    """Settings read when the process opens its display (before the first GL context), and
    the check that a forked child can open one (see the module docstring)."""
    if _FORKED_WITH_DISPLAY:
        raise RenderingUnavailableError(FORK_HINT)
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


def track_gl_owner(owner: GLOwner) -> None:
    """``owner`` holds GL contexts now: they are released before this process forks."""
    global _rendered
    _rendered = True
    _OWNERS.add(owner)


def _egl_display_open() -> bool:
    egl = sys.modules.get("mujoco.egl")
    return egl is not None and getattr(egl, "EGL_DISPLAY", None) is not None


def release_gl_before_fork() -> None:
    """Free every tracked GL context and MuJoCo's EGL display (run by ``os.fork``)."""
    if not _rendered:
        return  # nothing of ours ever rendered here: leave other libraries' displays alone
    for owner in list(_OWNERS):
        try:
            owner.release_gl()
        except Exception:  # noqa: BLE001 - a fork must not fail; the child then refuses GL
            continue
        _OWNERS.discard(owner)
    if _OWNERS or not _egl_display_open():
        return
    egl = sys.modules["mujoco.egl"]
    try:  # eglTerminate; MuJoCo's next context initialises the display again
        egl._terminate_display()
    except Exception:  # noqa: BLE001 - as above
        pass


def _after_fork_in_child() -> None:
    global _FORKED_WITH_DISPLAY
    _FORKED_WITH_DISPLAY = _egl_display_open()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(before=release_gl_before_fork, after_in_child=_after_fork_in_child)
