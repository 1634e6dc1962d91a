"""Worker processes that die with the process that started them.

A ``ProcessPoolExecutor``'s workers outlive a parent killed by SIGKILL (no ``atexit``, no
shutdown): they sit re-parented to PID 1, holding hundreds of MB, waiting on a queue nobody
feeds. :func:`worker_pool` starts spawned workers whose initializer makes the kernel kill them
when the parent dies (``prctl(PR_SET_PDEATHSIG)`` on Linux) and, everywhere, starts a thread
that ends the worker once its parent process id changes (re-parenting), checked twice a second.
A spawned worker imports the built-in object catalogue only, so the initializer also installs the
objects the parent registered (:func:`scorbot_gym.objects.user_objects`).
"""

from __future__ import annotations

import ctypes
import multiprocessing
import os
import signal
import sys
import threading
from concurrent.futures import ProcessPoolExecutor

PR_SET_PDEATHSIG = 1  # <linux/prctl.h>
PARENT_POLL_S = 0.5


def die_with_parent(parent_pid: int) -> None:
    """Pool initializer: end this process when ``parent_pid`` dies.

    ``PR_SET_PDEATHSIG`` fires when the *thread* that started the worker exits; the pools here
    are started from the thread that waits on their results, so that is the parent's lifetime.
    """
    if sys.platform.startswith("linux"):
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    if os.getppid() != parent_pid:  # the parent died before the line above
        os._exit(1)

    def watch() -> None:
        while not _parent_gone.wait(PARENT_POLL_S):
            if os.getppid() != parent_pid:
                os._exit(1)

    threading.Thread(target=watch, name="die-with-parent", daemon=True).start()


_parent_gone = threading.Event()  # never set: the watcher's sleep


def _start_worker(parent_pid: int, objects: tuple) -> None:
    from scorbot_gym.objects import install_objects

    die_with_parent(parent_pid)
    install_objects(objects)


def worker_pool(max_workers: int) -> ProcessPoolExecutor:
    """``max_workers`` spawned processes (no GL context or thread pool is inherited) that die
    with this process and know the objects registered in it."""
    from scorbot_gym.objects import user_objects

    return ProcessPoolExecutor(
        max_workers=max_workers,
        mp_context=multiprocessing.get_context("spawn"),
        initializer=_start_worker,
        initargs=(os.getpid(), user_objects()),
    )
