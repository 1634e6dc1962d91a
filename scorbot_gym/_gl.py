"""Pick a headless OpenGL backend for MuJoCo before anything imports ``mujoco``.

MuJoCo reads ``MUJOCO_GL`` when its rendering context is first created. With no display and no
choice made by the user, GLFW cannot open a window, so we default to EGL, which works both on
NVIDIA drivers and on Mesa's software rasterizer (llvmpipe) on CPU-only Linux machines.
"""

from __future__ import annotations

import os
import sys

VALID_BACKENDS = ("egl", "osmesa", "glfw")

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
