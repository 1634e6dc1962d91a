"""Time ``env.step`` of one environment; run inside whichever venv has that environment installed.

Run:  python benchmarks/peers/time_env.py ENV --steps 1000 [--image] [--seed 0]

Prints one JSON object on stdout: steps/s over the timed steps, the simulated seconds one step
advances, and the package versions in use. ``benchmarks/env_step.py --peers`` runs this script
once per repetition in each peer's own virtual environment (peers need mujoco 3.x; scorbot-gym
runs on mujoco 4), so every environment is timed by the same loop.

The loop: actions are drawn uniformly from the action space with ``--seed`` before timing;
only ``step`` calls (plus, with ``--image``, the one 320x240 RGB image per step) are timed;
episode resets are not. With ``--image`` each env renders with its own offscreen renderer
(``MUJOCO_GL`` must be ``egl`` on a headless machine). This file needs only the standard
library, numpy and the env's package: it must not import scorbot_gym for the peers.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Callable
from importlib import metadata

WIDTH, HEIGHT = 320, 240


class Timed:
    """An env reduced to what the timing loop needs: ``sample``, ``step``, ``reset``."""

    def __init__(self, step, reset, sample, dt: float, packages: tuple[str, ...], note: str):
        self.step, self.reset, self.sample = step, reset, sample
        self.dt, self.packages, self.note = dt, packages, note
        self.render_settings: dict = {}


def render_settings(model, shadows: bool | None = None) -> dict:
    """What makes a frame expensive in a software rasterizer: multisampling (MSAA: the
    offscreen buffer's samples per pixel, ``visual/quality/offsamples``), shadow maps and
    reflections. Read when the renderer is made (the first frame): a change after it is not
    what was timed."""
    casting = int(sum(model.light_castshadow))
    reflectance = [float(r) for r in model.mat_reflectance]
    return {
        "msaa_samples": int(model.vis.quality.offsamples),
        "shadow_casting_lights": casting,
        "shadows_rendered": bool(casting) if shadows is None else bool(shadows and casting),
        "shadow_map_size": int(model.vis.quality.shadowsize),
        "reflective_materials": sum(r > 0 for r in reflectance),
        "max_material_reflectance": max(reflectance, default=0.0),
    }


def _gym_env(env, dt: float, image: bool, packages: tuple[str, ...], note: str) -> Timed:
    """A Gymnasium env; with ``image`` and no camera in the observation, ``render()`` per step."""
    render_each_step = image and env.render_mode == "rgb_array"

    def step(a):
        _, _, terminated, truncated, _ = env.step(a)
        if render_each_step:
            frame = env.render()
            assert frame.shape[:2] == (HEIGHT, WIDTH), frame.shape
        return terminated or truncated

    def reset(seed):
        env.reset(seed=seed)

    return Timed(step, reset, env.action_space.sample, dt, packages, note)


def scorbot(
    image: bool,
    shadows: bool = False,
    action_type: str = "joint",
    pose: str | None = None,
    msaa: int | None = None,
    cartesian_ik: str = "closed_form",
) -> Timed:
    """``ScorbotGrasp-v0`` as ``gym.make`` gives it; ``pose="oracle"`` wraps it in
    ``PoseEstimateObservation`` with that source (scoring ``info["perception"]`` every step);
    ``msaa`` samples per pixel instead of the scene's (none), set before the first frame."""
    import gymnasium as gym

    import scorbot_gym  # noqa: F401  (registers the ids)

    kw = {"cameras": ["top"], "image_width": WIDTH, "image_height": HEIGHT} if image else {}
    env = gym.make(
        "ScorbotGrasp-v0",
        object_name="tomato_soup_can",
        shadows=shadows,
        action_type=action_type,
        cartesian_ik=cartesian_ik,
        **kw,
    )
    model = env.unwrapped.sim.model
    if msaa is not None:  # the render context is made at the first frame (the reset's)
        model.vis.quality.offsamples = msaa
    note = (
        "image = the 'top' camera's RGB in the observation (rendered inside step)"
        if image
        else "no image (no camera in the observation, nothing rendered)"
    )
    if pose is not None:
        from scorbot_gym.wrappers import PoseEstimateObservation

        env = PoseEstimateObservation(env, pose, keep_images=True)
        note += f"; wrapped in PoseEstimateObservation({pose!r})"
    timed = _gym_env(env, env.unwrapped.dt, False, ("scorbot-gym", "mujoco", "gymnasium"), note)
    timed.render_settings = render_settings(model, shadows)
    timed.env = env
    return timed


def profile_scorbot(timed: Timed, steps: int, seed: int, warmup: int) -> dict:
    """Where a scorbot step's time goes: the env's own stages timed in place (each wraps one
    method of the unwrapped env: a fraction of a microsecond per call), the rest of
    ``env.step`` (action checks, instability test, info, Gymnasium's wrappers) as ``other``.
    Mean microseconds per step over ``steps`` steps; ``physics`` is MuJoCo's ``mj_step``."""
    env = timed.env.unwrapped
    spent: dict[str, float] = {}

    def clocked(part: str, fn):
        def run(*args, **kwargs):
            t0 = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                spent[part] = spent.get(part, 0.0) + time.perf_counter() - t0

        return run

    for sim, _, task in env._sims.values():  # every scene the env has compiled
        sim.step = clocked("physics", sim.step)
        sim.render = clocked("rendering", sim.render)
        task.update = clocked("task (contacts, bookkeeping)", task.update)
        task.reward = clocked("task (contacts, bookkeeping)", task.reward)
        task.failure_cause = clocked("task (contacts, bookkeeping)", task.failure_cause)
    env._cartesian_target = clocked("action mapping (IK)", env._cartesian_target)
    wrapper = timed.env
    if hasattr(wrapper, "_estimate"):  # PoseEstimateObservation: its estimate and scoring
        wrapper._estimate = clocked("pose wrapper (estimate, scoring)", wrapper._estimate)
    env._observation = clocked("observation (incl. rendering)", env._observation)
    total = time_steps(timed, steps, seed, warmup, spent)[2]
    # the stages ran during warm-up too: time_steps cleared them when timing began
    parts = {k: 1e6 * v / steps for k, v in spent.items()}
    if "rendering" in parts:  # shown on its own: the observation's share is the rest of it
        parts["observation (incl. rendering)"] -= parts["rendering"]
        parts["observation (excl. rendering)"] = parts.pop("observation (incl. rendering)")
    step_us = 1e6 * total / steps
    parts["other (action checks, info, wrappers)"] = step_us - sum(parts.values())
    return {
        "step_us": step_us,
        "parts_us": parts,
        "shares": {k: v / step_us for k, v in parts.items()},
        "physics_share": parts.get("physics", 0.0) / step_us,
    }


def fetch(image: bool, msaa: int | None = None) -> Timed:
    """``FetchPickAndPlace-v4``; ``msaa`` samples per pixel instead of its model's (MuJoCo's
    default, 4), set before its renderer is made (at the first ``render()``)."""
    import gymnasium as gym
    import gymnasium_robotics

    gym.register_envs(gymnasium_robotics)
    kw = {"render_mode": "rgb_array", "width": WIDTH, "height": HEIGHT} if image else {}
    env = gym.make("FetchPickAndPlace-v4", **kw)
    if msaa is not None:
        env.unwrapped.model.vis.quality.offsamples = msaa
    note = (
        "image = env.render() after each step (its default external camera)"
        if image
        else "no image (nothing rendered)"
    )
    pkgs = ("gymnasium-robotics", "mujoco", "gymnasium")
    timed = _gym_env(env, env.unwrapped.dt, image, pkgs, note)
    timed.render_settings = render_settings(env.unwrapped.model)
    timed.env = env
    return timed


def metaworld(image: bool) -> Timed:
    import gymnasium as gym
    import metaworld  # noqa: F401  (registers Meta-World/MT1)

    kw = {"render_mode": "rgb_array", "width": WIDTH, "height": HEIGHT} if image else {}
    env = gym.make("Meta-World/MT1", env_name="pick-place-v3", camera_name="corner", **kw)
    note = "image = env.render() after each step ('corner' camera)" if image else "no image"
    pkgs = ("metaworld", "mujoco", "gymnasium")
    timed = _gym_env(env, env.unwrapped.dt, image, pkgs, note)
    timed.render_settings = render_settings(env.unwrapped.model)
    return timed


def robosuite_lift(image: bool) -> Timed:
    import numpy as np
    import robosuite

    env = robosuite.make(
        "Lift",
        robots="Panda",
        has_renderer=False,
        has_offscreen_renderer=image,
        use_camera_obs=image,
        camera_names="agentview",
        camera_widths=WIDTH,
        camera_heights=HEIGHT,
        ignore_done=False,
        horizon=500,
    )
    low, high = env.action_spec
    rng = np.random.default_rng(0)

    def step(a):
        obs, _, done, _ = env.step(a)
        if image:
            assert obs["agentview_image"].shape[:2] == (HEIGHT, WIDTH)
        return done

    def reset(seed):
        rng.bit_generator.state = np.random.default_rng(seed).bit_generator.state
        env.reset()

    note = "image = 'agentview' RGB in the observation (use_camera_obs)" if image else "no image"
    note += "; default OSC controller"
    timed = Timed(
        step,
        reset,
        lambda: rng.uniform(low, high),
        1.0 / env.control_freq,
        ("robosuite", "mujoco"),
        note,
    )
    timed.render_settings = render_settings(env.sim.model._model)
    return timed


ENVS: dict[str, Callable[[bool], Timed]] = {
    "ScorbotGrasp-v0": scorbot,
    "ScorbotGrasp-v0/shadows": lambda image: scorbot(image, shadows=True),
    "ScorbotGrasp-v0/cartesian": lambda image: scorbot(image, action_type="cartesian"),
    # the damped-least-squares IK every step, as before the closed form (2026-11-28)
    "ScorbotGrasp-v0/cartesian_dls": lambda image: scorbot(
        image, action_type="cartesian", cartesian_ik="dls"
    ),
    "ScorbotGrasp-v0/pose-oracle": lambda image: scorbot(image, pose="oracle"),
    # Fetch's multisampling: the render settings matched both ways
    "ScorbotGrasp-v0/msaa4": lambda image: scorbot(image, msaa=4),
    "FetchPickAndPlace-v4": fetch,
    "FetchPickAndPlace-v4/msaa0": lambda image: fetch(image, msaa=0),
    "Meta-World/pick-place-v3": metaworld,
    "robosuite/Lift-Panda": robosuite_lift,
}


def time_steps(
    env: Timed, steps: int, seed: int, warmup: int, clear: dict | None = None
) -> tuple[float, float, float]:
    """Steps per wall second and per CPU second (this process, all threads: the rendering
    threads too) over ``steps`` timed steps after ``warmup`` untimed ones, and the timed
    seconds. On a machine shared with other work the wall figure depends on the load; the CPU
    figure much less. ``clear`` (a profile's accumulators) is emptied when timing begins."""
    env.reset(seed)
    actions = [env.sample() for _ in range(steps + warmup)]
    for a in actions[:warmup]:
        if env.step(a):
            env.reset(None)
    if clear is not None:
        clear.clear()
    elapsed = cpu = 0.0
    for a in actions[warmup:]:
        c0, t0 = time.process_time(), time.perf_counter()
        done = env.step(a)
        elapsed += time.perf_counter() - t0
        cpu += time.process_time() - c0
        if done:
            env.reset(None)
    return steps / elapsed, steps / cpu, elapsed


def _version(pkg: str) -> str | None:
    try:
        return metadata.version(pkg)
    except metadata.PackageNotFoundError:
        return None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("env", choices=sorted(ENVS))
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--warmup", type=int, default=50)
    parser.add_argument("--image", action="store_true", help="one 320x240 RGB image per step")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--profile", action="store_true", help="scorbot envs: time the step's stages instead"
    )
    args = parser.parse_args(argv)
    if args.steps < 1 or args.warmup < 0:
        raise SystemExit(f"--steps must be >= 1 and --warmup >= 0, got {args.steps}, {args.warmup}")
    if args.profile and not args.env.startswith("ScorbotGrasp"):
        raise SystemExit(f"--profile times scorbot-gym's stages only, not {args.env}")

    env = ENVS[args.env](args.image)
    if args.profile:
        print(json.dumps(profile_scorbot(env, args.steps, args.seed, args.warmup)))
        return 0
    rate, cpu_rate, _ = time_steps(env, args.steps, args.seed, args.warmup)
    out = {
        "env": args.env,
        "image": f"{WIDTH}x{HEIGHT}" if args.image else None,
        "steps": args.steps,
        "steps_per_second": rate,
        "steps_per_cpu_second": cpu_rate,
        "sim_seconds_per_step": env.dt,
        "sim_seconds_per_wall_second": rate * env.dt,
        "note": env.note,
        "render_settings": env.render_settings,
        "versions": {p: _version(p) for p in env.packages},
        "python": sys.version.split()[0],
        "cpu_affinity": sorted(os.sched_getaffinity(0)),
    }
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
