"""Checks of a sweep made before its folder is written and any training starts, beside the memory
check (:mod:`sb3_pm.experiments.memory_needs`): the update device and the variants that take it."""

from __future__ import annotations

from typing import Any

from sb3_pm.errors import InputError
from sb3_pm.experiments.spec import Variant


def check_update_device_takers(update_device: str, cells: list[Any]) -> None:
    """Refuse, before any training, an update device torch cannot use here, or one for a learned
    variant whose learners cannot take it (only DCBF-PPO learners move their updates).

    :raises InputError: naming the device, or the variant and its algorithm.
    """
    from sb3_pm.experiments.runner import cell_config
    from sb3_pm.ppo_dcbf.update_device import check_update_device

    check_update_device(update_device)
    checked: set[str] = set()
    for cell in cells:
        variant = Variant(**cell.variant)
        if variant.kind == "baseline" or not variant.train or variant.key in checked:
            continue
        checked.add(variant.key)
        algo = cell_config(cell, variant).algo
        if algo != "dcbf_ppo":
            raise InputError(f"--update-device needs dcbf_ppo learners; variant {variant.key!r} uses {algo}")


__all__ = ["check_update_device_takers"]
