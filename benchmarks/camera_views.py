"""Render the README picture: what each fixed camera sees at reset and during a scripted lift.

Run:  python benchmarks/camera_views.py [--object tomato_soup_can] [--out PATH.png]

The committed picture is rebuilt with
``python benchmarks/camera_views.py --out benchmarks/results/camera_views.png --overwrite``.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--object", default="tomato_soup_can")
    parser.add_argument("--seed", type=int, default=4)
    from scorbot_gym.experiments.outputs import Outputs, add_overwrite_option

    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        help="where to write (default: runs/camera_views-<time>/camera_views.png; an existing "
        "file is refused without --overwrite)",
    )
    add_overwrite_option(parser)
    args = parser.parse_args(argv)
    try:  # before any work: an existing file is not replaced unless asked
        args.out = Outputs("camera_views", args.overwrite).path(
            args.out, "camera_views.png", "--out"
        )
    except ValueError as exc:
        parser.error(str(exc))

    import cv2
    import numpy as np

    from pose.fileio import atomic_write_bytes
    from scorbot_gym.envs.factory import make_env
    from scorbot_gym.policies import ScriptedGraspPolicy

    env = make_env(pose="oracle", object_name=args.object, shadows=True)
    obs, info = env.reset(seed=args.seed)
    sim = env.unwrapped.sim  # the benchmark renders extra views; policies never do this
    cams = ("top", "side", "overview")

    def row(label: str) -> np.ndarray:
        tiles = []
        for cam in cams:
            img = np.ascontiguousarray(sim.render(cam, width=320, height=240))
            cv2.putText(
                img, f"{cam} {label}", (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 2
            )
            tiles.append(img)
        return np.hstack(tiles)

    rows = [row("(reset)")]
    ctrl = ScriptedGraspPolicy.for_env(env)
    ctrl.reset(obs, info)
    for _ in range(200):  # stop while the object is held in the air
        obs, _, terminated, truncated, info = env.step(ctrl.act(obs))
        if info["held_time"] > 0.2 or terminated or truncated:
            break
    rows.append(row("(lifted)"))
    grid = np.vstack(rows)
    ok, png = cv2.imencode(".png", cv2.cvtColor(grid, cv2.COLOR_RGB2BGR))
    atomic_write_bytes(args.out, png.tobytes())
    print(f"written {args.out} ({len(png) // 1024} KiB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
