"""Check a config entry's values against :mod:`sb3_pm.zoo.schema`, once, where the file is read.

Every error is one line that names where the value was written (``file: entry.key``), so a typo
or an out-of-range number fails before anything trains. Team and algorithm values are returned
normalised (``5e4`` -> 50000, ``1e-4`` -> 0.0001, as PyYAML reads both as strings; ``lin_<x>``
stays as written); ``policy_kwargs`` and ``env_kwargs`` reach the policy and the environment as
written, so their values must already have the right type.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from sb3_pm.errors import InputError
from sb3_pm.zoo.schema import KEYS, POLICY_KEYS, REMOVED_KEYS, RESEARCH_TAG, REWARD_PRESETS, Key


class ConfigError(InputError):
    """A malformed config; the message names the file, the entry and the key."""


def _in_range(key: Key, number: float) -> bool:
    if math.isnan(number):
        return False
    if key.low is not None and (number < key.low or (key.low_open and number == key.low)):
        return False
    if key.high is not None and (number > key.high or (key.high_open and number == key.high)):
        return False
    # A bound left open at infinity still refuses infinity itself: no key takes an infinite value.
    return not math.isinf(number)


def _fail(key: Key, where: str, expected: str, value: Any) -> ConfigError:
    return ConfigError(f"{where}: expected {expected}, got {value!r}")


def _number_text(key: Key, what: str) -> str:
    """``an integer >= 1``, ``a number in (0, 1]``, ``a number or null``."""
    allowed = key.range_text()
    if not allowed:
        return what
    return f"{what} in {allowed}" if allowed.startswith(("(", "[")) else f"{what} {allowed}"


def _as_number(value: Any, loose: bool) -> float | None:
    """``value`` as a number, or ``None``; ``loose`` reads YAML's ``1e-4`` strings as numbers."""
    if isinstance(value, bool):
        return None
    if isinstance(value, (int, float)):
        return float(value)
    if loose and isinstance(value, str):
        try:
            return float(value)
        except ValueError:
            return None
    return None


def check_value(key: Key, value: Any, where: str, loose: bool = False) -> Any:
    """``value`` checked against ``key``; returned normalised where ``loose`` (team and algorithm
    keys), as written otherwise.

    :param where: names the value in errors (``file: entry.key``).
    :raises ConfigError: one line naming ``where``, what was expected and what was found.
    """
    if value is None:
        if key.nullable:
            return None
        if key.kind in ("mapping", "list") and key.default is not None:
            return value  # an empty block written as ``key:`` is the empty default
        raise _fail(key, where, f"a value ({key.kind}), not null", value)
    kind = key.kind
    if kind == "bool":
        if not isinstance(value, bool):
            raise _fail(key, where, "true/false", value)
        return value
    if kind == "int":
        number = _as_number(value, loose)
        if number is None or not (number.is_integer() and (loose or isinstance(value, int))):
            raise _fail(key, where, _number_text(key, "an integer"), value)
        if not _in_range(key, number):
            raise _fail(key, where, _number_text(key, "an integer"), value)
        return int(number) if loose else value
    if kind == "deploy_temperature":
        from sb3_pm.policies.sampling import check_deploy_temperature  # lazy: imports torch

        try:
            return check_deploy_temperature(value)
        except InputError as error:
            raise ConfigError(f"{where}: {error} (null acts by the argmax)") from None
    if kind in ("float", "schedule"):
        text = value.strip() if isinstance(value, str) else None
        schedule = kind == "schedule" and text is not None and text.startswith("lin_")
        number = _as_number(text[len("lin_") :] if schedule else value, loose or schedule)
        expected = "a number or lin_<number>" if kind == "schedule" else "a number"
        if number is None or not _in_range(key, number):
            raise _fail(key, where, _number_text(key, expected), value)
        if schedule:
            return text  # kept as written; the team turns it into a schedule
        return float(number) if loose else value
    if kind == "str":
        if not isinstance(value, str) or (key.choices and value not in key.choices):
            expected = f"one of {', '.join(map(str, key.choices))}" if key.choices else "a name"
            expected = key.expects or expected
            raise _fail(key, where, expected, value)
        return value
    if kind == "mapping":
        if not isinstance(value, Mapping):
            kind_name = type(value).__name__
            raise ConfigError(f"{where}: expected a mapping (not a string to eval), got {kind_name}")
        return dict(value)
    if kind == "list":
        if not isinstance(value, (list, tuple)):
            raise _fail(key, where, "a list", value)
        return value
    if kind == "reward":
        return check_reward(value, where)
    if kind == "deploy_filter":
        from sb3_pm.policies.dcbf import check_deploy_filter  # lazy: the module imports torch

        try:
            return check_deploy_filter(value)
        except InputError as error:
            raise ConfigError(f"{where}: {error} (null: the filter as trained)") from None
    return value  # kind "any"


def check_reward(value: Any, where: str) -> Any:
    """A reward preset name or a ``{term: weight}`` mapping of the schema's terms."""
    if isinstance(value, str):
        if value not in REWARD_PRESETS:
            presets = ", ".join(REWARD_PRESETS)
            raise ConfigError(f"{where}: unknown reward preset {value!r} (presets: {presets})")
        return value
    if not isinstance(value, Mapping) or not value:
        raise ConfigError(f"{where}: expected a preset name or a mapping {{term: weight}}, got {value!r}")
    for term, weight in value.items():
        if term not in KEYS["reward"]:
            raise ConfigError(f"{where}: unknown reward term {term!r} (terms: {', '.join(KEYS['reward'])})")
        if isinstance(weight, bool) or not isinstance(weight, (int, float)) or not math.isfinite(weight):
            raise ConfigError(f"{where}.{term}: expected a finite number, got {weight!r}")
    return value


def check_mapping(
    values: Mapping[str, Any], keys: Mapping[str, Key], where: str, what: str, loose: bool = False
) -> dict[str, Any]:
    """Each of ``values`` checked against its key among ``keys``.

    :param what: what ``keys`` are, for the unknown-key error (``an argument of the environment``).
    :raises ConfigError: for an unknown key or a bad value, naming it.
    """
    checked: dict[str, Any] = {}
    for name, value in values.items():
        if name not in keys:
            raise ConfigError(f"{where}: unknown key {name!r} (not {what})")
        checked[name] = check_value(keys[name], value, f"{where}.{name}", loose)
    return checked


def check_batch(settings: Mapping[str, Any], n_envs: int, where: str) -> None:
    """Refuse a ``batch_size`` the settings set larger than a rollout (``n_steps × n_envs``): SB3
    would train on smaller minibatches than written, without a word. (Left out, SB3's default of
    64 applies, and a short test rollout keeps working.)"""
    if "batch_size" not in settings:
        return
    n_steps = settings.get("n_steps", KEYS["algorithm"]["n_steps"].default)
    batch_size = settings.get("batch_size", KEYS["algorithm"]["batch_size"].default)
    if batch_size > n_steps * n_envs:
        raise ConfigError(
            f"{where}.batch_size: expected at most n_steps × n_envs = {n_steps} × {n_envs} = "
            f"{n_steps * n_envs} (one rollout), got {batch_size}"
        )


def check_settings(settings: Mapping[str, Any], where: str) -> None:
    """Check, before any config is read, settings that will be merged into a config entry (an
    experiment's or a variant's ``hyperparams``): every key a team or algorithm key, every value in
    its range, ``policy_kwargs`` and ``env_kwargs`` keys known. The merged entry is checked again,
    whole, by :func:`~sb3_pm.zoo.config.load_config` (which knows the algorithm and the policy).

    :raises ConfigError: naming ``where`` and the key.
    """
    entry_keys = {**KEYS["team"], **KEYS["algorithm"]}
    checked = check_mapping(settings, entry_keys, where, "a team key, nor an algorithm key", loose=True)
    check_mapping(checked.get("policy_kwargs") or {}, POLICY_KEYS, f"{where}.policy_kwargs", "a policy key")
    check_mapping(checked.get("env_kwargs") or {}, KEYS["env"], f"{where}.env_kwargs", "an env key")


def check_removed(settings: Mapping[str, Any], where: str) -> None:
    """Refuse a removed research switch (:data:`~sb3_pm.zoo.schema.REMOVED_KEYS`) among
    ``settings``' keys, its ``policy_kwargs`` and its ``env_kwargs`` reward terms, naming it and the
    tag that has it.

    :param settings: a config entry or a learner's hyperparameters (``env_kwargs`` may be among them).
    :raises ConfigError: for the first removed switch found.
    """
    written = [str(key) for key in settings]
    policy_kwargs = settings.get("policy_kwargs")
    if isinstance(policy_kwargs, Mapping):
        written += [str(key) for key in policy_kwargs]
        written.append(f"laplacian: {policy_kwargs.get('laplacian')}")
    env_kwargs = settings.get("env_kwargs")
    reward = env_kwargs.get("reward") if isinstance(env_kwargs, Mapping) else None
    if isinstance(reward, Mapping):
        written += [f"reward: {term}" for term in reward]
    for name in written:
        if name in REMOVED_KEYS:
            raise ConfigError(
                f"{where}: {REMOVED_KEYS[name]} {name!r} was removed from sb3_pm; "
                f"the research snapshot tag {RESEARCH_TAG} has it"
            )


__all__ = [
    "ConfigError",
    "check_batch",
    "check_mapping",
    "check_removed",
    "check_reward",
    "check_settings",
    "check_value",
]
