"""``--track``: a training run mirrored to Weights & Biases, as rl-zoo's ``--track`` does.

The run's TensorBoard logs (every learner's run and the team's) are synced to a W&B run named
after the run folder, with the resolved config as its config. W&B's own settings apply: with
``WANDB_MODE=offline`` the run is written under ``RUN/wandb/`` and uploaded later with
``wandb sync``; nothing else of the training changes. The optional extra ``track`` installs
``wandb``.
"""

from __future__ import annotations

import argparse
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from sb3_pm.errors import UsageError


def add_tracking_options(parser: argparse.ArgumentParser) -> None:
    """``--track``, ``--wandb-project`` and ``--wandb-entity``."""
    parser.add_argument(
        "--track",
        action="store_true",
        help="mirror the run's TensorBoard logs to Weights & Biases (pip install -e '.[track]'; "
        "WANDB_MODE=offline keeps it on this machine)",
    )
    parser.add_argument("--wandb-project", default="sb3_pm", help="W&B project (default sb3_pm)")
    parser.add_argument("--wandb-entity", default=None, help="W&B entity (default: your default entity)")


def check_tracking(args: argparse.Namespace) -> None:
    """Refuse ``--track`` without ``wandb`` installed, before any folder is written."""
    if getattr(args, "track", False):
        try:
            import wandb  # noqa: F401
        except ImportError:
            raise UsageError(
                "--track needs wandb: pip install wandb (or, in a checkout, pip install -e '.[track]')"
            ) from None


@contextmanager
def tracked(args: argparse.Namespace, out: Path, config: dict[str, Any]) -> Iterator[Any]:
    """With ``--track``, a W&B run that syncs the TensorBoard logs written inside the block
    (``None`` without it); it is finished when the block ends, failed or not."""
    if not getattr(args, "track", False):
        yield None
        return
    import wandb

    run = wandb.init(
        project=args.wandb_project,
        entity=args.wandb_entity,
        name=out.name,
        dir=str(out),
        config=config,
        sync_tensorboard=True,  # every learner's TensorBoard run, and the team's
        reinit="finish_previous",
    )
    try:
        yield run
    finally:
        run.finish()


__all__ = ["add_tracking_options", "check_tracking", "tracked"]
