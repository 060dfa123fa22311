"""Learner hyperparameters as plain JSON, the form a saved team's manifest records them in.

A saved team is rebuilt through its constructor from its manifest, never unpickled
(:mod:`sb3_pm.agents.deployment.model_files`), so its hyperparameters are written the way a config
file writes them: numbers and strings, ``lin_<x>`` schedules, and classes in ``policy_kwargs``
(``activation_fn`` ...) by their registry names (:mod:`sb3_pm.zoo.registry`). :func:`plain_hyperparams`
turns a team's hyperparameters into that form and refuses what has none (a Python function as a
schedule, an object in ``policy_kwargs``); :func:`check_plain_hyperparams` checks a manifest's
before the team is built from them; :func:`model_hyperparams` reads them back from a live SB3
model, for converting a team saved in the old format.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from sb3_pm.errors import InputError
from sb3_pm.zoo.registry import CLASS_KEYS

#: The constructor arguments of SB3's PPO (and MaskablePPO, DCBFPPO) that :func:`model_hyperparams`
#: reads back from a model's attributes of the same name.
PPO_KEYS = (
    "learning_rate",
    "n_steps",
    "batch_size",
    "n_epochs",
    "gamma",
    "gae_lambda",
    "clip_range",
    "clip_range_vf",
    "normalize_advantage",
    "ent_coef",
    "vf_coef",
    "max_grad_norm",
    "use_sde",
    "sde_sample_freq",
    "target_kl",
    "rollout_buffer_kwargs",
    "policy_kwargs",
)


def class_name(value: type, key: str) -> str:
    """A class's registry name for ``key`` (``Tanh``, or a name given to
    :func:`~sb3_pm.zoo.registry.register_class`).

    :raises InputError: for a class the registry does not name: a saved team names classes the way
        a config does, never by import path.
    """
    for name, registered in CLASS_KEYS[key].items():
        if registered is value:
            return name
        if isinstance(registered, str):
            module, _, attr = registered.partition(":")
            if attr == value.__qualname__ and (
                module == value.__module__ or getattr(_module(module), attr, None) is value
            ):
                return name
    raise InputError(
        f"policy_kwargs.{key} {value.__module__}.{value.__qualname__} has no registry name, so a saved "
        f"team could not name it: register it with sb3_pm.zoo.registry.register_class({key!r}, name, cls)"
    )


def _module(name: str) -> Any:
    import importlib

    try:
        return importlib.import_module(name)
    except ImportError:  # pragma: no cover - the registry's own modules
        return None


def schedule_value(value: Any, key: str, where: str) -> Any:
    """A schedule or number as a config writes it: a float, or ``lin_<x>`` for SB3's linear decay
    from ``x`` to 0 over training (what ``lin_<x>`` builds).

    :raises InputError: for a schedule no config string builds.
    """
    from stable_baselines3.common.utils import ConstantSchedule, FloatSchedule, LinearSchedule

    if isinstance(value, FloatSchedule):
        value = value.value_schedule
    if isinstance(value, ConstantSchedule):
        value = value.val
    if isinstance(value, LinearSchedule) and value.end == 0.0 and value.end_fraction == 1.0:
        return f"lin_{float(value.start)!r}"
    if isinstance(value, (int, float, np.floating, np.integer)) and not isinstance(value, bool):
        return float(value)
    if value is None or isinstance(value, str):
        return value
    raise InputError(
        f"{where}: {key} is a {type(value).__name__}, which a saved team cannot record; give it as a "
        "number or lin_<number>"
    )


def plain_value(value: Any, key: str, where: str) -> Any:
    """``value`` as JSON data (NumPy scalars as numbers, tuples as lists).

    :raises InputError: for anything else, naming ``key``.
    """
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        if not math.isfinite(value):
            raise InputError(f"{where}: {key} = {value} cannot be recorded in a saved team")
        return float(value)
    if isinstance(value, (list, tuple)):
        return [plain_value(v, key, where) for v in value]
    if isinstance(value, Mapping) and all(isinstance(k, str) for k in value):
        return {k: plain_value(v, f"{key}.{k}", where) for k, v in value.items()}
    raise InputError(
        f"{where}: {key} is a {type(value).__name__}, which a saved team cannot record as plain data"
    )


def plain_hyperparams(hyperparams: Mapping[str, Any], where: str) -> dict[str, Any]:
    """A team's hyperparameters in the manifest's JSON form (see the module docstring).

    :raises InputError: for a value that has no such form, naming it.
    """
    from sb3_pm.zoo.schedules import SCHEDULE_KEYS

    plain: dict[str, Any] = {}
    for key, value in hyperparams.items():
        if key in SCHEDULE_KEYS:
            plain[key] = schedule_value(value, key, where)
        elif key == "policy_kwargs" and isinstance(value, Mapping):
            kwargs = {}
            for name, item in value.items():
                if name in CLASS_KEYS and isinstance(item, type):
                    kwargs[name] = class_name(item, name)
                else:
                    kwargs[name] = plain_value(item, f"policy_kwargs.{name}", where)
            plain[key] = kwargs
        else:
            plain[key] = plain_value(value, key, where)
    return plain


def check_plain_hyperparams(hyperparams: Any, where: str) -> dict[str, Any]:
    """A manifest's hyperparameters, checked to be what :func:`plain_hyperparams` writes: a mapping
    of plain values whose class names are registry names.

    :raises InputError: for anything else.
    """
    if not isinstance(hyperparams, Mapping):
        raise InputError(f"{where} must be a mapping, got {type(hyperparams).__name__}")
    checked = plain_hyperparams(hyperparams, where)  # refuses anything but JSON data
    for key in CLASS_KEYS:
        name = (checked.get("policy_kwargs") or {}).get(key)
        if isinstance(name, str) and name not in CLASS_KEYS[key]:
            raise InputError(
                f"{where}: policy_kwargs.{key} {name!r} is not a registered name; a saved team names no "
                f"other code (register your own class with sb3_pm.zoo.registry.register_class before loading)"
            )
    return checked


def saved_hyperparams(where: Any, manifest: Mapping[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """A manifest's ``hyperparams`` and ``per_agent`` overrides, each checked by
    :func:`check_plain_hyperparams` (``where`` names the manifest in errors), without ``n_envs``.

    :raises InputError: for anything but plain hyperparameters.
    """
    per_agent = manifest.get("per_agent") or {}
    if not isinstance(per_agent, Mapping):
        raise InputError(f"{where}: per_agent must be a mapping of agents to hyperparameters")
    hyperparams = check_plain_hyperparams(manifest.get("hyperparams") or {}, f"{where} hyperparams")
    overrides = {str(a): check_plain_hyperparams(v, f"{where} per_agent.{a}") for a, v in per_agent.items()}
    # The manifest's own n_envs governs (a team may be loaded with another number of copies).
    for values in (hyperparams, *overrides.values()):
        values.pop("n_envs", None)
    return hyperparams, overrides


def constructor_keys(cls: type) -> set[str]:
    """The keyword arguments ``cls`` takes, following ``**kwargs`` up its bases (``DCBFPPO`` hands
    them to ``MaskablePPO``)."""
    keys: set[str] = set()
    for klass in cls.__mro__:
        if "__init__" not in vars(klass):
            continue
        parameters = inspect.signature(klass.__init__).parameters.values()
        keys |= {p.name for p in parameters if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)}
        if not any(p.kind is p.VAR_KEYWORD for p in parameters):
            break
    return keys


def model_hyperparams(model: Any, where: str) -> dict[str, Any]:
    """The constructor arguments a live SB3 PPO-style ``model`` was built with, in JSON form.

    :raises InputError: for a value that has no such form.
    """
    accepted = constructor_keys(type(model))
    values: dict[str, Any] = {}
    for key in PPO_KEYS:
        if key in accepted and hasattr(model, key):
            values[key] = getattr(model, key)
    if "stats_window_size" in accepted and hasattr(model, "_stats_window_size"):
        values["stats_window_size"] = model._stats_window_size
    if values.get("clip_range_vf") is None:
        values.pop("clip_range_vf", None)
    if not values.get("rollout_buffer_kwargs"):
        values.pop("rollout_buffer_kwargs", None)
    return plain_hyperparams(values, where)


__all__ = [
    "PPO_KEYS",
    "check_plain_hyperparams",
    "class_name",
    "model_hyperparams",
    "plain_hyperparams",
    "saved_hyperparams",
    "schedule_value",
]
