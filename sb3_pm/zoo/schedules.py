"""rl-zoo style schedule strings: ``lin_3e-4`` decays linearly from 3e-4 to 0 over training.

SB3 calls a schedule with ``progress_remaining`` (1 at the start of ``learn()``, 0 at the end).
The schedule object is SB3's own picklable :class:`~stable_baselines3.common.utils.LinearSchedule`,
so a saved model reloads without this package's help.
"""

from __future__ import annotations

from typing import Any

from stable_baselines3.common.utils import LinearSchedule

from sb3_pm.errors import InputError

#: Hyperparameters that SB3's PPO accepts as a schedule as well as a number.
SCHEDULE_KEYS = ("learning_rate", "clip_range", "clip_range_vf")


def parse_schedule(value: Any, key: str = "value") -> Any:
    """Turn ``"lin_<x>"`` into a linear schedule from ``x`` to 0; numbers (and numeric strings such as
    YAML's ``1e-4``, which PyYAML reads as a string) become floats; anything else is returned as is.

    :raises ValueError: for ``lin_`` followed by something that is not a number.
    """
    if isinstance(value, str):
        text = value.strip()
        if text.startswith("lin_"):
            try:
                start = float(text[len("lin_") :])
            except ValueError as error:
                raise InputError(
                    f"{key}: {value!r} is not a schedule; write lin_<number>, e.g. lin_3e-4"
                ) from error
            return LinearSchedule(start, 0.0, 1.0)
        try:
            return float(text)
        except ValueError:
            return value
    return value


__all__ = ["SCHEDULE_KEYS", "parse_schedule"]
