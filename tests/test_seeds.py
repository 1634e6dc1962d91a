"""The named seed ranges (#49 item 6): what trains never replays a placement that is evaluated.

A seed is a placement (same seed, same scene), so a training episode on an evaluation seed
puts the test set into the training set. ``scorbot_gym.seeds`` names every range; these tests
check that they are pairwise disjoint and that the code takes its seeds from them.
"""

from __future__ import annotations

import itertools
import runpy
from pathlib import Path

import pytest

from scorbot_gym import seeds
from scorbot_gym.seeds import RANGES, SeedRange

ROOT = Path(__file__).resolve().parents[1]


def test_every_range_is_listed_and_named_once():
    defined = [v for v in vars(seeds).values() if isinstance(v, SeedRange)]
    assert sorted(r.name for r in defined) == sorted(r.name for r in RANGES)
    assert len({r.name for r in RANGES}) == len(RANGES)
    assert {r.purpose for r in RANGES} == {"evaluation", "training"}


@pytest.mark.parametrize("a, b", list(itertools.combinations(RANGES, 2)), ids=lambda r: r.name)
def test_seed_ranges_are_pairwise_disjoint(a, b):
    assert a.start < a.stop and b.start < b.stop
    assert not a.overlaps(b), f"{a.name} [{a.start}, {a.stop}) overlaps {b.name}"
    for edge in (a.start, a.stop - 1):  # the ends of one range lie outside the other
        assert edge not in b and seeds.range_of(edge) is a


def test_overlap_is_detected():
    """The check above can fail: two ranges sharing one seed overlap."""
    a = SeedRange("a", 0, 10, "evaluation", "")
    assert a.overlaps(SeedRange("b", 9, 20, "training", ""))
    assert not a.overlaps(SeedRange("c", 10, 20, "training", ""))


def test_every_training_block_stays_inside_its_range():
    for r in seeds.TRAINING_RANGES:
        last = r.block(seeds.MAX_RUN_SEED, seeds.BLOCK)
        assert last.start in r and last[-1] in r and last.stop == r.stop
        assert r.block(0, 5) == range(r.start, r.start + 5)
        assert r.block(1, 5)[0] == r.start + seeds.BLOCK, "each training seed has its own block"


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda: seeds.DAGGER.block(seeds.MAX_RUN_SEED + 1, 1), "training seed must be in 0..999"),
        (lambda: seeds.DAGGER.block(-1, 1), "training seed must be in 0..999"),
        (lambda: seeds.DEMONSTRATIONS.block(0, seeds.BLOCK + 1), "exceed its block"),
        (lambda: seeds.TEST.seeds(50_000, 60_000), "leave the test range"),
        (lambda: seeds.check_run_seed(5000), "seed must be an integer in 0..999"),
    ],
)
def test_seeds_outside_their_range_are_one_line_errors(call, message):
    with pytest.raises(ValueError, match=message):
        call()


def test_the_training_run_and_trainers_take_their_seeds_from_the_ranges():
    from scorbot_gym.rl.imitation import ImitationConfig
    from scorbot_gym.rl.training import EVAL_SEED, TrainConfig

    assert EVAL_SEED == seeds.TRAINING_EVALUATION.start
    assert seeds.range_of(EVAL_SEED + 999) is seeds.TRAINING_EVALUATION
    with pytest.raises(ValueError, match="seed must be an integer in 0..999"):
        TrainConfig(seed=1000).validate()
    with pytest.raises(ValueError, match="seed must be an integer in 0..999"):
        ImitationConfig(seed=1000)
    with pytest.raises(ValueError, match="exceed its block"):
        ImitationConfig(dagger_rounds=2, dagger_episodes=seeds.BLOCK)


def test_benchmarks_evaluate_on_evaluation_seeds():
    compare = runpy.run_path(str(ROOT / "benchmarks" / "compare.py"), run_name="not_main")
    assert compare["EVAL_SEED"] == seeds.TEST.start
    for script in ("learned_policy.py", "finetune.py", "pixel_policy.py"):
        text = (ROOT / "benchmarks" / script).read_text()
        assert "default=seeds.TEST.start" in text, script
    for script, first in (("closed_loop.py", 1000), ("clutter_closed_loop.py", 5000)):
        assert f"default={first}" in (ROOT / "benchmarks" / script).read_text()
        assert seeds.range_of(first) is seeds.BENCHMARKS
