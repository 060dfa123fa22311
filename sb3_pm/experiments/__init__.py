"""Reproducing the paper's experiments: YAML experiment definitions, a resumable sweep runner, and
local or Ray backends (``sb3-pm reproduce``)."""

from sb3_pm.experiments.backends import BACKENDS, run_jobs
from sb3_pm.experiments.runner import EVAL_SEED_OFFSET, Cell, plan_cells, reproduce, run_cell
from sb3_pm.experiments.spec import Experiment, ExperimentError, Variant, load_experiment

__all__ = [
    "BACKENDS",
    "EVAL_SEED_OFFSET",
    "Cell",
    "Experiment",
    "ExperimentError",
    "Variant",
    "load_experiment",
    "plan_cells",
    "reproduce",
    "run_cell",
    "run_jobs",
]
