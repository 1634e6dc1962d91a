"""The episode-seed ranges, named, in one place: what trains never replays what is evaluated.

An env reset with seed ``s`` always places the same object the same way, so a seed is a
placement. A learned policy judged on placements it was trained on is judged on its training
set. Every piece of code that picks episode seeds takes them from a range here, and
``tests/test_seeds.py`` checks that the ranges are pairwise disjoint.

Evaluation ranges (``purpose="evaluation"``):

- ``DEFAULT`` [0, 1,000): ``scorbot-gym rollout`` / ``compare`` without ``--seed``, and the
  tests: what a user runs first.
- ``BENCHMARKS`` [1,000, 50,000): the closed-loop, recognition, clutter, tilt and blob-split
  benchmarks (first seeds 1,000, 5,000, 7,000, ...).
- ``TEST`` [50,000, 90,000): the paired comparison of the arms (``benchmarks/compare.py``,
  ``learned_policy.py``, ``finetune.py``, ``pixel_policy.py``): the figures we report.
- ``VALIDATION`` [90,000, 100,000): choosing between trained variants, never the test seeds.
- ``TRAINING_EVALUATION`` [1,000,000, 1,100,000): the evaluations made during a training run
  (``scorbot-gym train``'s learning curve and its ``best/`` policy).

Training ranges (``purpose="training"``), one block of :data:`BLOCK` seeds per training seed
(``run_seed``, at most :data:`MAX_RUN_SEED`), so runs of different seeds see different
placements:

- ``DEMONSTRATIONS`` [100,000,000, 200,000,000): scripted demonstrations (imitation BC, the
  demonstrations of ``train --bc-demos`` and of a fine-tune's buffer, ``scorbot-gym demos``).
- ``DAGGER`` [200,000,000, 300,000,000): DAgger rounds (state and pixel imitation).
- ``TRAINING_ENVS`` [300,000,000, 400,000,000): the first reset of each SB3 training env (later
  episodes continue the env's own random stream, which no seeded reset reproduces).

Policies trained before this module (shipped ``learned`` / ``finetuned``) used demonstration
seeds from 0 and DAgger seeds from 1,000,000 (inside today's ``DEFAULT`` and
``TRAINING_EVALUATION``); their ``policy.json`` says so. This module imports nothing.
"""

from __future__ import annotations

from dataclasses import dataclass

#: seeds per training seed in a training range
BLOCK = 100_000
#: the largest training seed whose block fits in a training range
MAX_RUN_SEED = 999


@dataclass(frozen=True)
class SeedRange:
    """Seeds ``[start, stop)`` kept for one use."""

    name: str
    start: int
    stop: int
    purpose: str  # "evaluation" or "training"
    use: str

    def __contains__(self, seed: object) -> bool:
        return isinstance(seed, int) and self.start <= seed < self.stop

    def overlaps(self, other: SeedRange) -> bool:
        return self.start < other.stop and other.start < self.stop

    def seeds(self, n: int, first: int | None = None) -> range:
        """``n`` seeds from ``first`` (default: the range's start), all inside the range."""
        first = self.start if first is None else int(first)
        if n < 0 or first not in self or (n and first + n > self.stop):
            raise ValueError(
                f"{n} seeds from {first} leave the {self.name} range "
                f"[{self.start}, {self.stop}) ({self.use})"
            )
        return range(first, first + n)

    def block(self, run_seed: int, n: int, offset: int = 0) -> range:
        """Seeds ``offset .. offset + n - 1`` of training seed ``run_seed``'s block."""
        if isinstance(run_seed, bool) or not isinstance(run_seed, int):
            raise ValueError(f"a training seed must be an integer, got {run_seed!r}")
        if not 0 <= run_seed <= MAX_RUN_SEED:
            raise ValueError(
                f"training seed must be in 0..{MAX_RUN_SEED} (each has {BLOCK:,} {self.name} "
                f"seeds of its own), got {run_seed}"
            )
        if n < 0 or offset < 0 or offset + n > BLOCK:
            raise ValueError(
                f"{offset + n} {self.name} episodes for one training seed exceed its block "
                f"of {BLOCK:,}"
            )
        first = self.start + run_seed * BLOCK + offset
        return range(first, first + n)

    def to_json(self) -> dict[str, object]:
        return {"range": self.name, "start": self.start, "stop": self.stop}


DEFAULT = SeedRange("default", 0, 1_000, "evaluation", "rollout/compare without --seed, tests")
BENCHMARKS = SeedRange(
    "benchmarks", 1_000, 50_000, "evaluation", "closed-loop and perception benchmarks"
)
TEST = SeedRange("test", 50_000, 90_000, "evaluation", "the reported comparison of the arms")
VALIDATION = SeedRange(
    "validation", 90_000, 100_000, "evaluation", "choosing between trained variants"
)
TRAINING_EVALUATION = SeedRange(
    "training_evaluation",
    1_000_000,
    1_100_000,
    "evaluation",
    "evaluations during a training run (learning curve, best/)",
)
DEMONSTRATIONS = SeedRange(
    "demonstrations",
    100_000_000,
    200_000_000,
    "training",
    "scripted demonstrations (imitation, train --bc-demos, fine-tune buffer, scorbot-gym demos)",
)
DAGGER = SeedRange("dagger", 200_000_000, 300_000_000, "training", "DAgger rounds")
TRAINING_ENVS = SeedRange(
    "training_envs", 300_000_000, 400_000_000, "training", "first reset of each SB3 training env"
)

RANGES = (
    DEFAULT,
    BENCHMARKS,
    TEST,
    VALIDATION,
    TRAINING_EVALUATION,
    DEMONSTRATIONS,
    DAGGER,
    TRAINING_ENVS,
)
EVALUATION_RANGES = tuple(r for r in RANGES if r.purpose == "evaluation")
TRAINING_RANGES = tuple(r for r in RANGES if r.purpose == "training")


def range_of(seed: int) -> SeedRange | None:
    """The named range holding ``seed`` (``None`` outside all of them)."""
    return next((r for r in RANGES if seed in r), None)


def check_run_seed(seed: int, what: str = "seed") -> None:
    """One-line error for a training seed whose seed blocks do not exist."""
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= MAX_RUN_SEED:
        raise ValueError(
            f"{what} must be an integer in 0..{MAX_RUN_SEED} (each training seed has seed "
            f"blocks of its own in scorbot_gym.seeds), got {seed!r}"
        )


__all__ = [
    "BENCHMARKS",
    "BLOCK",
    "DAGGER",
    "DEFAULT",
    "DEMONSTRATIONS",
    "EVALUATION_RANGES",
    "MAX_RUN_SEED",
    "RANGES",
    "TEST",
    "TRAINING_ENVS",
    "TRAINING_EVALUATION",
    "TRAINING_RANGES",
    "VALIDATION",
    "SeedRange",
    "check_run_seed",
    "range_of",
]
