"""Learning curves of the learned-grasping arms: success vs env steps and vs training wall time.

Each arm is one ``scorbot-gym train`` run (oracle pose, Cartesian actions, whole catalogue):

- ``residual``: SAC learning a residual on top of the scripted controller (sees it at every
  step; the shipped policy);
- ``bc``: SAC whose actor is first behaviour-cloned from 100 scripted episodes (which also
  seed the replay buffer), then fine-tuned online (saw the controller only in demonstrations);
- ``scratch``: plain SAC (never saw the controller), on a small budget.

A run directory that already holds an arm is resumed up to its budget (or reused as it is), so
the curves of runs started with the CLI are collected rather than recomputed. Success is
measured by the runs' own evaluation callback: deterministic policy, held-out seeds from
1,000,000, 20 episodes per point.

    python benchmarks/rl_training.py [--runs runs] [--arms residual bc scratch]
"""

from __future__ import annotations

import argparse
import io
import json
import os
import platform
import sys
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

ARMS = {
    "residual": {"residual": True, "timesteps": 10_000},
    "bc": {"bc_demos": 100, "bc_steps": 3000, "timesteps": 5000, "eval_every": 2500},
    "scratch": {"timesteps": 3000, "eval_every": 1000, "checkpoint_every": 1000},
}
RUN_NAMES = {
    "residual": "residual_sac_oracle",
    "bc": "bc_sac_oracle",
    "scratch": "scratch_sac_oracle",
}


def main(argv: list[str] | None = None) -> int:
    from scorbot_gym.experiments.outputs import Outputs, add_overwrite_option

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=Path, default=Path("runs"), help="run directories")
    parser.add_argument("--arms", nargs="+", choices=sorted(ARMS), default=list(ARMS))
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        help="results JSON, the PNG beside it (default: runs/rl_training-<time>/rl_training.json)",
    )
    add_overwrite_option(parser)
    args = parser.parse_args(argv)
    try:  # before any work: an existing file is not replaced unless asked
        args.out = Outputs("rl_training", args.overwrite).path(
            args.out, "rl_training.json", companions=[".png"]
        )
    except ValueError as exc:
        parser.error(str(exc))

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    import scorbot_gym
    from pose.fileio import atomic_write_bytes, atomic_write_json
    from scorbot_gym.rl import TrainConfig, resume, train

    report: dict = {"benchmark": "rl_training", "arms": {}}
    for arm in args.arms:
        out = args.runs / RUN_NAMES[arm]
        config = TrainConfig(**ARMS[arm], progress_bar=False)
        if not (out / "config.json").exists():
            state = train(config, out)
        else:
            state = json.loads((out / "checkpoint" / "state.json").read_text())
            if state["timesteps"] < config.timesteps:
                state = resume(out, timesteps=config.timesteps)
        used = json.loads((out / "config.json").read_text())
        report["arms"][arm] = {
            "run": str(out),
            "config": used,
            "timesteps": state["timesteps"],
            "train_wall_s": state["wall_s"],
            "steps_per_s": state["timesteps"] / state["wall_s"] if state["wall_s"] else None,
            "demos": state.get("demos"),
            "curve": state["eval"],
        }
        last = state["eval"][-1]
        print(
            f"{arm:>9}: {last['success_rate']:.1%} (95% CI {last['ci95'][0]:.1%}-"
            f"{last['ci95'][1]:.1%}) after {state['timesteps']} steps, {state['wall_s']:.0f} s"
        )
    report["machine"] = {
        "platform": platform.platform(),
        "cpu_count": os.cpu_count(),
        "load_avg_1m_at_end": os.getloadavg()[0],
        "scorbot_gym": scorbot_gym.__version__,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_json(args.out, report)

    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    for arm, rec in report["arms"].items():
        curve = rec["curve"]
        ys = [c["success_rate"] for c in curve]
        lo = [c["ci95"][0] for c in curve]
        hi = [c["ci95"][1] for c in curve]
        for ax, key, scale in ((axes[0], "timesteps", 1e-3), (axes[1], "wall_s", 1 / 60)):
            xs = [c[key] * scale for c in curve]
            ax.plot(xs, ys, marker="o", label=arm)
            ax.fill_between(xs, lo, hi, alpha=0.15)
    axes[0].set_xlabel("environment steps (thousands)")
    axes[1].set_xlabel("training wall time (min, evaluation excluded)")
    axes[0].set_ylabel("success rate (20 held-out episodes, 95% CI)")
    axes[0].set_ylim(-0.02, 1.02)
    for ax in axes:
        ax.legend()
        ax.grid(alpha=0.3)
    fig.suptitle("SAC on ScorbotGraspCartesian-v0, oracle pose, whole catalogue")
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    atomic_write_bytes(args.out.with_suffix(".png"), buf.getvalue())
    print(f"written {args.out} and {args.out.with_suffix('.png')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
