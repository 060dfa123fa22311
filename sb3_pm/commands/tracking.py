"""``--track``: a training run mirrored to Weights & Biases, as rl-zoo's ``--track`` does.

``sb3-pm train --track``: the run's TensorBoard logs (every learner's run and the team's) are
synced to a W&B run named after the run folder, with the resolved config as its config.
``sb3-pm reproduce --track``: each training cell of the sweep is one such run
(:func:`tracking_of`, carried by the cells). W&B's own settings apply: with ``WANDB_MODE=offline``
the run is written under ``RUN/wandb/`` and uploaded later with ``wandb sync``; nothing else of
the training changes. The optional extra ``track`` installs ``wandb``
(:mod:`sb3_pm.experiments.tracking` opens the runs).
"""

from __future__ import annotations

import argparse
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sb3_pm.errors import InputError, UsageError

if TYPE_CHECKING:  # imported where used: sb3_pm.experiments is heavy for every command's start
    from sb3_pm.experiments.tracking import Tracking


def add_tracking_options(parser: argparse.ArgumentParser, what: str = "the run's TensorBoard logs") -> None:
    """``--track`` (its help says it mirrors ``what``), ``--wandb-project`` and ``--wandb-entity``."""
    parser.add_argument(
        "--track",
        action="store_true",
        help=f"mirror {what} to Weights & Biases (pip install -e '.[track]'; "
        "WANDB_MODE=offline keeps it on this machine)",
    )
    parser.add_argument("--wandb-project", default="sb3_pm", help="W&B project (default sb3_pm)")
    parser.add_argument("--wandb-entity", default=None, help="W&B entity (default: your default entity)")


def check_tracking(args: argparse.Namespace) -> None:
    """Refuse ``--track`` without ``wandb`` installed, before any folder is written."""
    if getattr(args, "track", False):
        from sb3_pm.experiments.tracking import check_wandb

        try:
            check_wandb("--track")
        except InputError as error:
            raise UsageError(str(error)) from None


def tracking_of(args: argparse.Namespace, group: str | None = None) -> Tracking | None:
    """The W&B project and entity given with ``--track`` (runs grouped under ``group``), or
    ``None`` without ``--track``."""
    if not getattr(args, "track", False):
        return None
    from sb3_pm.experiments.tracking import Tracking

    return Tracking(project=args.wandb_project, entity=args.wandb_entity, group=group)


@contextmanager
def tracked(args: argparse.Namespace, out: Path, config: dict[str, Any]) -> Iterator[Any]:
    """With ``--track``, a W&B run named after ``out`` that syncs the TensorBoard logs written
    inside the block (``None`` without it); it is finished when the block ends, failed or not."""
    from sb3_pm.experiments.tracking import wandb_run

    with wandb_run(tracking_of(args), out, out.name, config) as run:
        yield run


__all__ = ["add_tracking_options", "check_tracking", "tracked", "tracking_of"]
