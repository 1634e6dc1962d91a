"""Give freed heap memory back to the operating system.

glibc keeps memory freed by large, short-lived allocations (the MJCF compiler's scratch space,
software GL's texture and display-list storage replaced on a scene switch) in its heap, where it
counts as resident memory for the life of the process. ``malloc_trim`` returns it; elsewhere
(macOS, musl) this does nothing.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools


@functools.cache
def _malloc_trim():
    name = ctypes.util.find_library("c")
    return getattr(ctypes.CDLL(name), "malloc_trim", None) if name else None


def release_freed_memory() -> None:
    """``malloc_trim(0)`` where glibc provides it (about 0.5 ms)."""
    trim = _malloc_trim()
    if trim is not None:
        trim(0)
