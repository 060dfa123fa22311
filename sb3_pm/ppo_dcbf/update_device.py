"""Run a learner's PPO update on another torch device than its rollouts.

A team's rollout step is a few hundred small tensor operations per learner on ``n_envs`` maps:
on a GPU each is a kernel launch that costs more than its arithmetic, so rollouts run faster on
the CPU. The update phase is the opposite: ten epochs of minibatches of ``(batch, N, N)``
attention scores, which a GPU computes several times faster than two CPU cores from 200 nodes on
(research/LOG.md §3i, "On a GPU"). :func:`on_update_device` moves a learner's policy, the PPO
optimizer's state and its rollout buffer's output device to the update device for the length of
``train()`` and back afterwards, so everything outside ``train()`` (rollouts, the stacked acting
pass, the estimator fit, saving) sees a CPU learner.

Nothing else changes: the same minibatches in the same order, the same loss. The update's
arithmetic is the update device's, so a run is not the CPU run bit for bit (as with ``device:
cuda``), and on a GPU not even its own rerun: the attention layers' scatter sums use atomic
additions there, whose order varies. Seeded bit-for-bit reproducibility is the CPU's.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import torch as th

from sb3_pm.errors import InputError


def check_update_device(device: str | th.device | None) -> th.device | None:
    """``device`` as a :class:`torch.device`, or ``None``; refuses a device torch cannot use here.

    Only ``cpu`` and ``cuda`` devices are taken (``cuda:i`` with ``i`` below the count of GPUs
    torch sees): an update moved to any other device type is untested, and one on ``meta`` would
    destroy the parameters.

    :raises InputError: naming the device, if it is malformed, of another type or absent here.
    """
    if device is None:
        return None
    if isinstance(device, str) and device.strip() == "auto":
        raise InputError("update_device: name the device (cuda, cuda:1, cpu); 'auto' is for --device")
    try:
        parsed = th.device(device)
    except (RuntimeError, TypeError):
        raise InputError(
            f"update_device: {device!r} is not a torch device (cpu, cuda, cuda:1, ...)"
        ) from None
    if parsed.type not in ("cpu", "cuda"):
        raise InputError(
            f"update_device: {device!r} is a {parsed.type} device; only cpu and cuda are supported"
        )
    if parsed.type == "cuda":
        if not th.cuda.is_available():
            raise InputError(f"update_device: {device!r} asked for, but torch sees no CUDA device here")
        if parsed.index is not None and parsed.index >= th.cuda.device_count():
            raise InputError(
                f"update_device: {device!r} asked for, but torch sees {th.cuda.device_count()} CUDA device(s)"
            )
    return parsed


def _move_optimizer_state(optimizer: th.optim.Optimizer, device: th.device) -> None:
    """Move ``optimizer``'s per-parameter state tensors (Adam's moments) to ``device``.

    Adam keeps its ``step`` counters on the CPU unless it is capturable or fused; they stay where
    they are, as torch's own ``load_state_dict`` leaves them.
    """
    for state in optimizer.state.values():
        for key, value in state.items():
            if key != "step" and isinstance(value, th.Tensor):
                state[key] = value.to(device)


def _move(model: Any, device: th.device) -> None:
    """Put ``model``'s policy, its PPO optimizer state and its rollout buffer's output on ``device``."""
    model.policy.to(device)
    _move_optimizer_state(model.policy.optimizer, device)
    model.rollout_buffer.device = device
    model.device = device


@contextmanager
def on_update_device(model: Any, device: th.device | None) -> Iterator[None]:
    """Within the block, ``model`` (an SB3 on-policy learner) lives on ``device``; afterwards (also
    after an error, one in the move itself included) on its own device again. ``None`` or the
    learner's own device changes nothing."""
    home = th.device(model.device)
    if device is None or device == home:
        yield
        return
    try:
        _move(model, device)  # inside: a move that fails half way is undone below
        yield
    finally:
        # Moving home is safe to repeat and to run on a half-moved learner. Should it fail too, the
        # error that stopped the update stays attached as its context (Python chains them).
        _move(model, home)


__all__ = ["check_update_device", "on_update_device"]
