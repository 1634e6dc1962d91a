"""Arms cut into chunks of seeds over worker processes give the episodes one process gives.

The closed-loop benchmark and the comparison run an arm's seeds in chunks
(:mod:`scorbot_gym.evaluation.chunks`); this holds only if every episode depends on its seed
alone: the object, its placement, the push, the perturbation and the pose noise are redrawn
from the episode's seed, and nothing the env or the estimator keeps carries over from the
episode before.
"""

from __future__ import annotations

import pytest

from scorbot_gym.cli import main
from scorbot_gym.evaluation import chunks
from scorbot_gym.evaluation.rollout import RolloutConfig, run_rollouts


@pytest.mark.parametrize(
    ("episodes", "jobs"),
    [((200,) * 16, 14), ((50, 50), 2), ((2,) * 6, 2), ((7,), 3), ((200,) * 12, 1),
     ((220,) * 6 + (110,) * 6 + (44,) * 11, 16), ((15, 3), 4)],
)  # fmt: skip
def test_chunks_cover_every_seed_once_in_order(episodes, jobs):
    tasks = [(n, 100 * i) for i, n in enumerate(episodes)]
    plans = chunks.plan_chunks(tasks, jobs)
    for (n, seed), plan in zip(tasks, plans, strict=True):
        seeds = [s for k, first in plan for s in range(first, first + k)]
        assert seeds == list(range(seed, seed + n))
        assert all(k >= min(n, chunks.MIN_CHUNK_EPISODES) for k, _ in plan)
        if jobs == 1:
            assert len(plan) == 1


def test_long_arms_are_spread_over_the_processes():
    assert len(chunks.plan_chunks([(200, 0)] * 16, 14)[0]) == 4
    # the closed-loop batch on 16 processes: a 220-episode arm in several chunks, no chunk
    # much longer than the batch's share per chunk
    batch = [(220, 0)] * 6 + [(110, 0)] * 6 + [(44, 0)] * 11
    plans = chunks.plan_chunks(batch, 16)
    assert len(plans[0]) >= 5 and max(k for p in plans for k, _ in p) <= 44


def test_bad_plans_are_refused():
    with pytest.raises(ValueError, match="jobs must be >= 1"):
        chunks.plan_chunks([(3, 0)], 0)
    with pytest.raises(ValueError, match="needs >= 1 episode"):
        chunks.plan_chunks([(3, 0), (0, 5)], 2)


def _outcomes(summary: dict, results: list) -> tuple:
    """What an arm measured, less its wall-clock times."""
    rows = []
    for r in results:
        p = dict(r.perception or {})
        p.pop("median_estimate_ms", None)
        p.pop("median_stage_ms", None)
        rows.append((r.seed, r.object_name, r.success, r.steps, r.failure_cause,
                     r.total_reward, p, r.extra))  # fmt: skip
    keys = ("episodes", "successes", "failure_causes", "per_object", "seed", "config")
    return rows, {k: summary[k] for k in keys}


@pytest.mark.slow
def test_chunked_rollouts_give_the_same_episodes_for_any_jobs(tmp_path, monkeypatch):
    """Two arms of three episodes, whole in one process and in one-episode chunks over two
    processes: the manifold estimator (a small box model, background subtraction) under a
    lighting perturbation, and the noisy oracle with the push disturbance."""
    model = tmp_path / "box.npz"
    argv = ["pose", "train", "--objects", "box", "--views", "108", "--width", "320"]
    argv += ["--height", "240", "--out", str(model), "--cache-dir", str(tmp_path), "--quiet"]
    assert main(argv) == 0
    configs = [
        RolloutConfig(pose="manifold", pose_model=str(model), objects=("box",),
                      perturbation="lighting=0.5", episodes=3, seed=7),
        RolloutConfig(pose="noisy", noise={"pos_sigma_m": 0.01, "yaw_sigma_deg": 10.0},
                      disturbance="push", objects=("box", "cylinder"), episodes=3, seed=7),
    ]  # fmt: skip
    monkeypatch.setattr(chunks, "MIN_CHUNK_EPISODES", 1)
    assert [len(p) for p in chunks.plan_chunks([(3, 7), (3, 7)], 2)] == [3, 3]
    whole = run_rollouts(configs, jobs=1)
    split = run_rollouts(configs, jobs=2)
    for (s1, r1), (s2, r2) in zip(whole, split, strict=True):
        assert [r.seed for r in r2] == [7, 8, 9]
        assert _outcomes(s1, r1) == _outcomes(s2, r2)
    assert whole[0][0]["perception"]["estimates"] > 0  # the estimator ran


def test_rollout_and_compare_take_jobs_and_a_ray_address():
    from scorbot_gym.cli import build_parser

    parser = build_parser()
    args = parser.parse_args(["rollout", "--jobs", "3", "--ray"])
    assert (args.jobs, args.ray) == (3, "local")
    args = parser.parse_args(["compare", "--policies", "scripted", "--ray", "ray://head:10001"])
    assert (args.jobs, args.ray) == (1, "ray://head:10001")
    assert parser.parse_args(["rollout"]).ray is None
    with pytest.raises(SystemExit):
        parser.parse_args(["rollout", "--jobs", "0"])


@pytest.mark.slow
@pytest.mark.ray
def test_ray_tasks_give_the_episodes_one_process_gives(monkeypatch):
    """The noisy oracle under the push, four episodes in one-episode chunks as tasks of a
    local Ray instance: the episodes of a plain run, seed for seed."""
    pytest.importorskip("ray")
    noise = {"pos_sigma_m": 0.01, "yaw_sigma_deg": 10.0}
    config = RolloutConfig(
        pose="noisy",
        noise=noise,
        disturbance="push",
        objects=("box", "banana"),
        episodes=4,
        seed=11,
    )
    monkeypatch.setattr(chunks, "MIN_CHUNK_EPISODES", 1)
    ((s1, r1),) = run_rollouts([config], jobs=1)
    ((s2, r2),) = run_rollouts([config], jobs=2, ray="local")
    assert [r.seed for r in r2] == [11, 12, 13, 14]
    assert _outcomes(s1, r1) == _outcomes(s2, r2)
