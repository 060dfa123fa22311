"""Sampling a policy's actions at a temperature: ``softmax(logits / T)`` over the allowed nodes."""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping
from typing import Any

import torch as th

from sb3_pm.errors import InputError


def check_temperature(temperature: object) -> float:
    """``temperature`` as a float.

    :raises InputError: anything but a positive finite number.
    """
    if isinstance(temperature, bool) or not isinstance(temperature, numbers.Real):
        raise InputError(f"the sampling temperature must be a number, got {temperature!r}")
    if not math.isfinite(temperature) or temperature <= 0:
        raise InputError(f"the sampling temperature must be positive and finite, got {temperature}")
    return float(temperature)


def check_deploy_temperature(temperature: object) -> float | None:
    """A team's deployment rule: ``None`` (act by the argmax) or a sampling temperature.

    :raises InputError: anything but ``None`` or a positive finite number.
    """
    return None if temperature is None else check_temperature(temperature)


def tempered_logits(logits: th.Tensor, masks: th.Tensor, temperature: float) -> th.Tensor:
    """Logits whose softmax over the allowed nodes is ``softmax(logits / temperature)`` there.

    The best allowed node is shifted to 0 before dividing: the mask's constant (-1e8 in
    sb3-contrib) is applied afterwards, and a small temperature would otherwise push every allowed
    logit below it, so that the draw would land on forbidden nodes. Forbidden entries are 0 here
    and must still be masked by the caller.

    :param logits: ``(B, N)`` the actor's logits.
    :param masks: ``(B, N)`` bool, the allowed nodes (at least one per row).
    :param temperature: positive and finite.
    :return: ``(B, N)``.
    """
    best = logits.masked_fill(~masks, float("-inf")).amax(-1, keepdim=True)
    return th.where(masks, logits - best, th.zeros_like(logits)) / temperature


def set_sampling_temperature(policies: Mapping[str, Any], temperature: object) -> None:
    """Set ``sampling_temperature`` on every policy of ``{name: policy}``, or on none.

    :raises InputError: a bad temperature (:func:`check_temperature`), or a policy without one
        (not a DCBF policy), naming it.
    """
    value = check_temperature(temperature)
    for name, policy in policies.items():
        if not hasattr(policy, "sampling_temperature"):
            raise InputError(f"{name} has no DCBF policy whose sampling temperature could be set")
    for policy in policies.values():
        policy.sampling_temperature = value
