"""A training run mirrored to Weights & Biases, as rl-zoo's ``--track`` does.

``sb3-pm train --track`` tracks its one run (:mod:`sb3_pm.commands.tracking`); ``sb3-pm reproduce
--track`` tracks each training cell of its sweep as one run, in the worker that trains it: the
cell carries its :class:`Tracking` (:attr:`sb3_pm.experiments.runner.Cell.tracking`), so nothing
reaches a worker through global state. A W&B run syncs the TensorBoard logs written while it is
open (every learner's run and the team's) and has the training config as its config. W&B's own
settings apply: with ``WANDB_MODE=offline`` the run is written under ``FOLDER/wandb/`` and uploaded
later with ``wandb sync``; nothing else of the training changes. The optional extra ``track``
installs ``wandb``.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sb3_pm.errors import InputError


@dataclass(frozen=True)
class Tracking:
    """Where tracked runs go: the W&B project, entity (``None``: the user's default) and group
    (``None``: none; a sweep groups its cells' runs under the experiment's name)."""

    project: str = "sb3_pm"
    entity: str | None = None
    group: str | None = None


def check_wandb(option: str = "--track") -> None:
    """Refuse tracking without ``wandb`` installed, in one line.

    :raises InputError: naming ``option`` and the install command.
    """
    try:
        import wandb  # noqa: F401
    except ImportError:
        raise InputError(
            f"{option} needs wandb: pip install wandb (or, in a checkout, pip install -e '.[track]')"
        ) from None


@contextmanager
def wandb_run(tracking: Tracking | None, folder: Path, name: str, config: dict[str, Any]) -> Iterator[Any]:
    """With ``tracking``, a W&B run named ``name`` under ``folder/wandb`` that syncs the
    TensorBoard logs written inside the block (``None`` without it); it is finished when the block
    ends, failed or not."""
    if tracking is None:
        yield None
        return
    import wandb

    run = wandb.init(
        project=tracking.project,
        entity=tracking.entity,
        group=tracking.group,
        name=name,
        dir=str(folder),
        config=config,
        sync_tensorboard=True,  # every learner's TensorBoard run, and the team's
        reinit="finish_previous",
    )
    try:
        yield run
    finally:
        run.finish()


__all__ = ["Tracking", "check_wandb", "wandb_run"]
