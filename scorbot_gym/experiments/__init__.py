"""Pose-estimator ablation sweeps: specs, per-trial cached jobs, local and Ray runners,
aggregation into the seed's Fig. 3 and a stage-ablation table."""

from scorbot_gym.experiments.ablation import ablate, write_report
from scorbot_gym.experiments.aggregate import aggregate, chance_level, stage_ablation
from scorbot_gym.experiments.runners import LocalRunner, RayRunner, make_jobs, run_sweep
from scorbot_gym.experiments.spec import EstimatorSpec, SweepSpec, parse_occlusions, sweep

__all__ = [
    "EstimatorSpec",
    "LocalRunner",
    "RayRunner",
    "SweepSpec",
    "ablate",
    "aggregate",
    "chance_level",
    "make_jobs",
    "parse_occlusions",
    "run_sweep",
    "stage_ablation",
    "sweep",
    "write_report",
]
