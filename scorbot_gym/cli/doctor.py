"""``scorbot-gym doctor``: which GL backend is in use, whether rendering works, how fast, and
whether the models the main job builds on first use are in the cache yet."""

from __future__ import annotations

import argparse
import time

from scorbot_gym import _gl


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "doctor", help="check headless rendering, frames per second and the default models"
    )
    p.add_argument("--frames", type=int, default=30, help="frames to time per size")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import mujoco
    import numpy as np

    from scorbot_gym.sim import Simulation

    print(f"mujoco {mujoco.__version__}, MUJOCO_GL={_gl.backend_in_use()}")
    try:
        sim = Simulation("tomato_soup_can")
        img = sim.render("top", width=64, height=48)
    except _gl.RenderingUnavailableError as exc:
        print(f"rendering: FAILED\n{exc}")
        return 1
    ok = img.shape == (48, 64, 3) and img.std() > 1.0
    print(f"rendering: {'ok' if ok else 'FAILED (blank image)'}")
    try:
        from OpenGL import GL

        print(f"GL renderer: {GL.glGetString(GL.GL_RENDERER).decode()}")
    except Exception:  # PyOpenGL is optional; the renderer string is informational only
        pass
    for w, h in ((320, 240), (640, 480)):
        sim.render("top", width=w, height=h)  # warm-up: context and texture upload
        times = []
        for _ in range(max(1, args.frames)):
            t0 = time.perf_counter()
            sim.render("top", width=w, height=h)
            times.append(time.perf_counter() - t0)
        med = float(np.median(times))
        print(f"{w}x{h}: {1.0 / med:7.1f} frames/s (median {med * 1e3:.1f} ms over {len(times)})")
    sim.close()
    _report_default_models()
    return 0 if ok else 1


def _report_default_models() -> None:
    """Whether the main job's first run will train (missing models are no failure)."""
    from scorbot_gym.data import default_cache_dir
    from scorbot_gym.perception.defaults import cache_entries, status_lines

    entries = cache_entries()
    print(
        "default models (rollout --pose manifold [--recognize], compare; cache "
        f"{default_cache_dir()}):"
    )
    print("\n".join(status_lines(entries)))
    if not all(e.present for e in entries):
        print(
            "  missing ones are built on the main job's first run (minutes); build them now "
            "with: scorbot-gym pose train --defaults"
        )
