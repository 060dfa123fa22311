"""rl-zoo style schedule strings: ``lin_3e-4`` decays linearly from 3e-4 to 0 over training.

SB3 calls a schedule with ``progress_remaining`` (1 at the start of ``learn()``, 0 at the end).
The schedule object is SB3's own picklable :class:`~stable_baselines3.common.utils.LinearSchedule`,
so a saved model reloads without this package's help.
"""

from __future__ import annotations

from typing import Any

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
            # Imported here: reading a config (and sb3_pm.zoo) must not import torch.
            from stable_baselines3.common.utils import LinearSchedule

            return LinearSchedule(start, 0.0, 1.0)
        try:
            return float(text)
        except ValueError:
            return value
    return value


def check_spread(spread: Any) -> float:
    """A learning-rate spread as a float: a finite number >= 1 (the fastest learner's rate over the
    slowest's; 1 = every learner the same).

    :raises InputError: for anything else (a bool, a string, below 1, infinite or NaN).
    """
    if isinstance(spread, bool) or not isinstance(spread, (int, float)) or not 1 <= spread < float("inf"):
        raise InputError(
            "learning_rate_spread: expected a number >= 1 (the fastest learner's rate over the "
            f"slowest's; 1 = every learner the same), got {spread!r}"
        )
    return float(spread)


def staggered_learning_rates(learning_rate: Any, spread: float, n_agents: int) -> list[Any]:
    """Each learner's learning rate when a team spreads them geometrically around ``learning_rate``.

    Learner ``i`` of ``K`` gets ``learning_rate * spread ** (1/2 - i / (K - 1))``: ``agent_0`` the
    fastest, the last learner ``spread`` times slower, the others evenly spaced on a log scale
    between them, and the geometric mean of the team's rates ``learning_rate`` itself. The range,
    not the step, is fixed, so a larger team stays within the rates a smaller one was tuned with.
    ``spread = 1`` (or a single learner) gives every learner ``learning_rate``.

    :param learning_rate: a number, or a ``lin_<x>`` string (the schedule's start is scaled).
    :returns: ``K`` values of the same kind (floats, or ``lin_<x>`` strings).
    :raises InputError: for a spread that is not a number >= 1, or a learning rate that is
        neither a number nor ``lin_<x>`` (a Python schedule cannot be scaled from a config).
    """
    spread = check_spread(spread)
    if n_agents == 1:
        factors = [1.0]
    else:
        factors = [spread ** (0.5 - i / (n_agents - 1)) for i in range(n_agents)]
    text = learning_rate.strip() if isinstance(learning_rate, str) else None
    if text is not None and text.startswith("lin_"):
        start = parse_schedule(text, "learning_rate").start
        return [f"lin_{start * factor!r}" for factor in factors]
    value = parse_schedule(learning_rate, "learning_rate")
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputError(
            "learning_rate_spread needs a learning_rate that is a number or lin_<number>, "
            f"got {learning_rate!r}"
        )
    return [float(value) * factor for factor in factors]


__all__ = ["SCHEDULE_KEYS", "check_spread", "parse_schedule", "staggered_learning_rates"]
