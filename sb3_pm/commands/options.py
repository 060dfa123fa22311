"""Command-line options that several commands share, defined once."""

from __future__ import annotations

import argparse
from typing import Any


def add_compute_options(parser: argparse.ArgumentParser, training: bool = False) -> None:
    """``--device`` and ``--threads`` (and, for training, ``--update-device``).

    One torch thread is the default everywhere: training is then bit-for-bit reproducible from its
    seed, and a learned team's small per-step forward passes gain nothing from intra-op threads
    (with torch's default thread count an evaluation episode took twice the wall time and four
    times the CPU time on 2 cores). Parallelism comes from processes (``reproduce --jobs``).
    """
    parser.add_argument(
        "--device", default="cpu", help="torch device of learned teams: cpu, cuda, auto (default cpu)"
    )
    if training:
        parser.add_argument(
            "--update-device",
            default=None,
            metavar="DEVICE",
            help="torch device of the learners' update phases alone, e.g. cuda with --device cpu: "
            "rollouts on the CPU, updates on the GPU (default: --device; with --resume, the run's own)",
        )
    reason = (
        "training is then bit-for-bit reproducible from --seed; with more threads some torch kernels "
        "reduce in a varying order"
        if training
        else "small per-step forward passes are fastest single-threaded"
    )
    parser.add_argument(
        "--threads", type=int, default=1, metavar="N", help=f"torch CPU threads (default 1: {reason})"
    )


def check_compute_options(args: Any) -> None:
    """Refuse ``--threads`` below 1 and a ``--device`` this host does not have, with one line,
    before any work starts."""
    from sb3_pm.errors import UsageError

    if args.threads < 1:
        raise UsageError(f"--threads must be at least 1, got {args.threads}")
    check_device(args.device, "--device")


def check_device(device: Any, flag: str) -> None:
    """Refuse a torch device that does not exist on this host (``cuda`` without a GPU), with one line.

    Left alone, SB3 falls back to the CPU without a word for ``cuda``, so a run meant for a GPU
    would take the CPU's hours unnoticed. ``cpu`` and ``auto`` (the GPU where there is one) always
    pass, without importing torch.

    :param flag: names the value in the error (``--device``, ``args.yml device``).
    """
    from sb3_pm.errors import UsageError

    if device is None or device in ("cpu", "auto"):
        return
    import torch

    try:
        parsed = torch.device(str(device))
    except (RuntimeError, TypeError):
        raise UsageError(f"{flag}: expected cpu, cuda, cuda:N or auto, got {device!r}") from None
    if parsed.type == "cuda":
        count = torch.cuda.device_count() if torch.cuda.is_available() else 0
        if count == 0:
            raise UsageError(f"{flag} {device}: this host has no CUDA GPU torch can use; use --device cpu")
        if parsed.index is not None and parsed.index >= count:
            raise UsageError(
                f"{flag} {device}: this host has {count} CUDA GPU(s) (cuda:0 to cuda:{count - 1})"
            )
    elif parsed.type == "mps" and not torch.backends.mps.is_available():
        raise UsageError(f"{flag} {device}: this host has no MPS device; use --device cpu")
    elif parsed.type not in ("cpu", "cuda", "mps"):
        raise UsageError(f"{flag}: expected cpu, cuda, cuda:N or auto, got {device!r}")


def check_seeds(seeds: Any, flag: str) -> None:
    """Refuse a negative seed with one line (numpy's seeding refuses it only deep in the first
    episode, with a traceback)."""
    from sb3_pm.errors import UsageError

    for seed in seeds:
        if seed < 0:
            raise UsageError(f"{flag} must be at least 0, got {seed}")


def check_writable(path: Any, flag: str) -> None:
    """Refuse an output file that cannot be written, before the long work that would fill it.

    Creates and removes a temporary file in the target folder: permission bits alone say nothing
    for root, and a "folder" that is a regular file fails only when written into.
    """
    import tempfile
    from pathlib import Path

    from sb3_pm.errors import UsageError

    if path is None:
        return
    folder = Path(path).parent
    if Path(path).is_dir():
        raise UsageError(f"{flag} {path} is a folder; give a file name")
    try:
        with tempfile.TemporaryFile(dir=folder):
            pass
    except FileNotFoundError:
        raise UsageError(f"{flag} {path}: output directory does not exist: {folder}") from None
    except OSError as error:
        raise UsageError(
            f"{flag} {path} cannot be written ({error.strerror or error}); choose another path"
        ) from None
