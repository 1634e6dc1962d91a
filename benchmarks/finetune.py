"""Fine-tune the shipped stand-alone policy (BC + DAgger) with SAC, RLPD-style, and measure the
imitation policy against its fine-tuned versions on the same fresh seeds (whole catalogue).

Each seed is one ``scorbot-gym train --init-policy learned --bc-demos N`` run (run folder under
``--runs``; ``--jobs`` runs train at once, one process each); then the scripted controller, the
imitation policy (``learned``) and every fine-tuned policy (the run's ``--checkpoint``: by
default the last, after the stated budget; ``best`` is chosen on the run's own evaluation
seeds, never on the test seeds) play the same ``--episodes`` seeded episodes from
``--eval-seed`` under the oracle pose and each ``--noise`` level. Reported: success with 95 %
Wilson CI, paired differences (fine-tuned - imitation, and each arm - scripted) with Newcombe
CIs and McNemar p, the training cost (demonstrations, env steps, wall time; the imitation
stage's from its policy.json) and the fine-tune's evaluation curve.

    nice -n 5 python benchmarks/finetune.py --timesteps 20000 --seeds 0 --episodes 200
    python benchmarks/finetune.py --timesteps 50000 --seeds 0,1,2 --jobs 16   # a big machine
    python benchmarks/finetune.py --skip-training --runs runs/finetune   # evaluate runs again

Writes ``--out`` (JSON) and the ``.png`` beside it, by default ``finetune.json`` in a new
``runs/finetune-<UTC time>/``; a named file that exists is refused unless ``--overwrite``
(the committed record: ``--out benchmarks/results/finetune.json --overwrite``). ``--config
NAME`` stores the run as the variant ``configs[NAME]`` of that file instead (e.g. another
``bc_coef``), without a figure, the file's other runs kept.
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

ARM_IMITATION, ARM_SCRIPTED = "learned", "scripted"


def _train_one(config_json: dict, out: str) -> dict:
    """One seed's run (a worker process's job)."""
    from scorbot_gym.rl.training import TrainConfig, train

    config = TrainConfig.from_json(config_json)
    if (Path(out) / "checkpoint" / "state.json").is_file():
        from scorbot_gym.rl.training import resume

        return resume(out)
    return train(config, out)


def _train(configs: dict[int, dict], runs: Path, jobs: int) -> None:
    tasks = [(cfg, str(runs / f"seed_{seed}")) for seed, cfg in configs.items()]
    if jobs <= 1 or len(tasks) == 1:
        for t in tasks:
            _train_one(*t)
        return
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(min(jobs, len(tasks)), mp_context=mp.get_context("spawn")) as pool:
        for f in [pool.submit(_train_one, *t) for t in tasks]:
            f.result()


def _run_record(run: Path, checkpoint: str) -> dict:
    """What a run folder records of its training (compact: no per-episode data)."""
    from scorbot_gym.rl import runs as runs_mod

    state = runs_mod.read_json(run / "checkpoint" / "state.json")
    config = runs_mod.read_json(run / "config.json")
    best = state.get("best") or {}
    return {
        "run": str(run),
        "seed": config["seed"],
        "pose": config["pose"],
        "noise_pos_m": config["noise_pos_m"] if config["pose"] == "noisy" else None,
        "noise_yaw_deg": config["noise_yaw_deg"] if config["pose"] == "noisy" else None,
        "env_steps": state["timesteps"],
        "wall_s": state["wall_s"],
        "demos": state.get("demos"),
        "hyperparams": config["hyperparams"],
        "checkpoint": checkpoint,
        "checkpoint_timesteps": best.get("timesteps") if checkpoint == "best" else None,
        "eval_curve": [
            {k: e[k] for k in ("timesteps", "wall_s", "episodes", "success_rate", "ci95")}
            for e in state["eval"]
        ],
    }


def _configs(args: argparse.Namespace, overrides: dict) -> dict[int, dict]:
    """One checked training configuration per seed (as JSON)."""
    from scorbot_gym.rl.training import TrainConfig

    return {
        seed: TrainConfig(
            init_policy=args.init_policy,
            normalize=False,
            pose=args.pose,
            noise_pos_m=args.noise_pos,
            noise_yaw_deg=args.noise_yaw,
            timesteps=args.timesteps,
            bc_demos=args.bc_demos,
            seed=seed,
            hyperparams=overrides,
            eval_every=args.eval_every,
            eval_episodes=args.eval_episodes,
            checkpoint_every=args.eval_every,
            progress_bar=False,
            tensorboard=False,
        )
        .validate()
        .to_json()
        for seed in args.seeds
    }


def _paired(record: dict) -> list[bool]:
    return [c == "1" for c in record["episode_success"]]


def _plot(report: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 4.5))
    for name, run in report["runs"].items():
        curve = run["eval_curve"]
        x = [e["timesteps"] for e in curve]
        y = [100 * e["success_rate"] for e in curve]
        lo = [100 * e["ci95"][0] for e in curve]
        hi = [100 * e["ci95"][1] for e in curve]
        ax1.plot(x, y, marker="o", label=f"{name} ({curve[-1]['episodes']} eval episodes)")
        ax1.fill_between(x, lo, hi, alpha=0.15)
    ax1.set_xlabel("fine-tuning env steps")
    ax1.set_ylabel("success on the run's evaluation seeds (%)")
    ax1.set_title("RLPD-style SAC fine-tuning from the imitation policy")
    ax1.legend(fontsize=8)
    ax1.grid(alpha=0.3)

    conds = [c["label"] for c in report["evaluation"]["conditions"]]
    arms = list(report["evaluation"]["arms"])
    width = 0.8 / len(arms)
    for i, arm in enumerate(arms):
        recs = {r["pose"]: r for r in report["evaluation"]["results"] if r["policy"] == arm}
        rates = np.array([100 * recs[c]["success_rate"] for c in conds])
        ci = np.array([[100 * v for v in recs[c]["ci95"]] for c in conds])
        xs = np.arange(len(conds)) + (i - (len(arms) - 1) / 2) * width
        label = report["evaluation"]["arms"][arm]["label"]
        ax2.bar(xs, rates, width, label=label)
        ax2.errorbar(xs, rates, yerr=[rates - ci[:, 0], ci[:, 1] - rates], fmt="none", c="k")
    ax2.set_xticks(np.arange(len(conds)), conds)
    ax2.set_ylabel(f"success, {report['episodes']} paired episodes (%), 95 % CI")
    ax2.set_ylim(0, 105)
    lines = []
    for d in report["finetuned_vs_imitation"]:
        lines.append(
            f"{d['pose']} {d['a']}: {100 * d['diff']:+.1f} "
            f"[{100 * d['ci95'][0]:+.1f}, {100 * d['ci95'][1]:+.1f}] p={d['mcnemar_p']:.2g}"
        )
    ax2.set_title("fine-tuned - imitation:\n" + "\n".join(lines), fontsize=8)
    ax2.legend(fontsize=8, loc="lower left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> None:
    from scorbot_gym import seeds
    from scorbot_gym.cli._args import non_negative_float, positive_int, seed_list
    from scorbot_gym.experiments.outputs import Outputs, add_overwrite_option, companion
    from scorbot_gym.rl import hyperparams as hparams

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--timesteps", type=positive_int, default=20_000, help="env steps per run")
    p.add_argument("--bc-demos", type=positive_int, default=100, help="demonstration episodes")
    p.add_argument("--seeds", type=seed_list, default=[0])
    p.add_argument("--init-policy", default="learned")
    p.add_argument("--pose", choices=("oracle", "noisy"), default="oracle", help="training pose")
    p.add_argument("--noise-pos", type=non_negative_float, default=0.02, help="--pose noisy (m)")
    p.add_argument("--noise-yaw", type=non_negative_float, default=20.0, help="--pose noisy (deg)")
    p.add_argument("--hyperparams", nargs="+", default=[], metavar="KEY=VALUE")
    p.add_argument("--eval-every", type=positive_int, default=5000)
    p.add_argument("--eval-episodes", type=positive_int, default=30)
    p.add_argument(
        "--checkpoint",
        choices=("best", "last"),
        default="last",
        help="last: the policy after --timesteps; best: the run's best evaluation (its "
        "evaluation at step 0 is the imitation policy itself, which a noisy small evaluation "
        "can keep as best)",
    )
    p.add_argument("--episodes", type=positive_int, default=200, help="test episodes per arm")
    p.add_argument("--eval-seed", type=int, default=seeds.TEST.start)
    p.add_argument(
        "--noise", nargs="*", default=["0:20", "0.02:0"], help="pose-noise levels S:Y tested"
    )
    p.add_argument(
        "--arms",
        default=f"{ARM_SCRIPTED},{ARM_IMITATION}",
        help="comma-separated arms besides the fine-tuned ones (scripted, learned)",
    )
    p.add_argument("--jobs", type=positive_int, default=1)
    p.add_argument("--runs", type=Path, default=Path("runs/finetune"))
    p.add_argument("--skip-training", action="store_true", help="evaluate the runs in --runs")
    p.add_argument("--out", type=Path, default=None, help="results JSON (the PNG goes beside it)")
    add_overwrite_option(p)
    p.add_argument(
        "--config",
        default=None,
        help="store the run as this named variant of --out (default: the file's main run)",
    )
    args = p.parse_args(argv)

    from pose.fileio import write_result
    from scorbot_gym.evaluation.compare import compare, noise_level, resolve_arm
    from scorbot_gym.evaluation.summary import newcombe_paired_diff
    from scorbot_gym.rl.runs import policy_dir

    arms = [a for a in args.arms.split(",") if a]
    baseline = args.init_policy  # the paired baseline of every fine-tuned policy: its start
    if baseline not in arms:
        arms.append(baseline)
    try:  # every setting is checked before any training: a usage error, not a traceback
        for arm in arms:
            resolve_arm(arm)
        for level in args.noise:
            noise_level(level)
        configs = _configs(args, hparams.parse_overrides(args.hyperparams))
        out_json = Outputs("finetune", args.overwrite).path(
            args.out, "finetune.json", companions=[".png"] if args.config is None else []
        )
    except (ValueError, FileNotFoundError) as exc:
        p.error(str(exc))
    t0 = time.perf_counter()
    if not args.skip_training:
        _train(configs, args.runs, args.jobs)
    train_wall = time.perf_counter() - t0
    runs = {f"finetuned_s{s}": args.runs / f"seed_{s}" for s in args.seeds}
    folders = {name: policy_dir(run, args.checkpoint) for name, run in runs.items()}
    policies = [*arms, *map(str, folders.values())]
    report = compare(
        policies,
        ["oracle"],
        args.episodes,
        seed=args.eval_seed,
        noise=args.noise,
        progress=False,
        jobs=args.jobs,
    )
    rename = {str(f): n for n, f in folders.items()}
    for r in report["results"]:
        r["policy"] = rename.get(r["policy"], r["policy"])
    report["arms"] = {rename.get(k, k): v for k, v in report["arms"].items()}
    for name in runs:
        report["arms"][name]["label"] = f"{name} (fine-tuned, {args.checkpoint})"
    for d in report["differences"]:
        d["a"] = rename.get(d["a"], d["a"])
    diffs = []
    for cond in report["conditions"]:
        by = {r["policy"]: r for r in report["results"] if r["pose"] == cond["label"]}
        base = by[baseline]
        for name in runs:
            d = newcombe_paired_diff(_paired(by[name]), _paired(base))
            diffs.append({"pose": cond["label"], "a": name, "b": baseline, **d})
    out = {
        "description": f"RLPD-style SAC fine-tuning of the imitation policy {baseline!r} "
        "(demonstrations in every batch, critic warm-up, actor initialised from the imitation "
        "MLP); imitation vs fine-tuned vs scripted on the same seeded episodes, whole "
        "catalogue, cartesian actions",
        "episodes": args.episodes,
        "eval_seeds": [args.eval_seed, args.eval_seed + args.episodes - 1],
        "runs": {n: _run_record(run, args.checkpoint) for n, run in runs.items()},
        "training_wall_s_all_runs": None if args.skip_training else round(train_wall, 1),
        "jobs": args.jobs,
        "finetuned_vs_imitation": diffs,
        "evaluation": {k: report[k] for k in ("conditions", "arms", "results", "differences")},
        "evaluation_wall_s": round(report["wall_s"], 1),
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform()},
    }
    write_result(out_json, out, args.config)
    if args.config is None:  # the figure is the main run's
        _plot(out, companion(out_json, ".png"))
    for d in diffs:
        print(
            f"{d['pose']:>14} {d['a']} - imitation: {100 * d['diff']:+.1f} points "
            f"[{100 * d['ci95'][0]:+.1f}, {100 * d['ci95'][1]:+.1f}], "
            f"McNemar p {d['mcnemar_p']:.3g}"
        )
    for r in out["evaluation"]["results"]:
        lo, hi = r["ci95"]
        print(f"{r['pose']:>14} {r['policy']:>14}: {r['success_rate']:.1%} [{lo:.1%}, {hi:.1%}]")
    where = f"config {args.config!r}" if args.config else companion(out_json, ".png").name
    print(f"results written to {out_json} ({where})")


if __name__ == "__main__":
    main()
