"""Name -> class registries for configs: algorithms, activation functions, optimizers, extractors.

A YAML config names classes by string (``algo: maskable_ppo``, ``activation_fn: ReLU``). They are
resolved here, never with ``eval`` and never by importing a path that a file names: a config is
data, and reading one from elsewhere must not run code. The built-in entries are ``"module:attr"``
strings of this package and its dependencies, imported on first use, so the registry costs nothing
to import and ``dcbf_ppo`` does not drag in torch-geometric until it is asked for. A class of your
own is made nameable in Python, by code you run, with :func:`register_class`.
"""

from __future__ import annotations

import importlib
from typing import Any

from sb3_pm.errors import InputError

#: Algorithms a team can be built from. ``dcbf_ppo`` is the paper's method (PPO with the DCBF policy).
ALGORITHMS: dict[str, str] = {
    "dcbf_ppo": "sb3_pm.ppo_dcbf:DCBFPPO",
    "maskable_ppo": "sb3_contrib:MaskablePPO",
    "ppo": "stable_baselines3:PPO",
}

#: The policy each algorithm uses when a config names none.
DEFAULT_POLICIES: dict[str, str] = {
    "dcbf_ppo": "DCBFPolicy",
    "maskable_ppo": "MultiInputPolicy",
    "ppo": "MultiInputPolicy",
}

ACTIVATIONS: dict[str, Any] = {
    name: f"torch.nn:{name}"
    for name in ("ReLU", "Tanh", "ELU", "LeakyReLU", "GELU", "SiLU", "Sigmoid", "Identity")
}

OPTIMIZERS: dict[str, Any] = {name: f"torch.optim:{name}" for name in ("Adam", "AdamW", "RMSprop", "SGD")}

FEATURES_EXTRACTORS: dict[str, Any] = {
    "CombinedExtractor": "stable_baselines3.common.torch_layers:CombinedExtractor",
    "FlattenExtractor": "stable_baselines3.common.torch_layers:FlattenExtractor",
    "GATFeaturesExtractor": "sb3_pm.policies.extractor:GATFeaturesExtractor",
}

#: Which ``policy_kwargs`` keys hold classes, and the registry that names them (values: import paths
#: of this package and its dependencies, or classes given to :func:`register_class`).
CLASS_KEYS: dict[str, dict[str, Any]] = {
    "activation_fn": ACTIVATIONS,
    "optimizer_class": OPTIMIZERS,
    "features_extractor_class": FEATURES_EXTRACTORS,
}


class RegistryError(InputError):
    """A name that no registry knows and that is not an importable ``module:attr`` path."""


def import_path(path: str) -> Any:
    """Import ``"package.module:attr"`` and return the attribute."""
    module_name, _, attr = path.partition(":")
    if not module_name or not attr:
        raise RegistryError(f"{path!r} is not a 'package.module:Name' import path")
    module = importlib.import_module(module_name)
    try:
        return getattr(module, attr)
    except AttributeError as error:
        raise RegistryError(f"module {module_name!r} has no attribute {attr!r}") from error


def lookup(registry: dict[str, Any], name: str, kind: str) -> Any:
    """Resolve ``name`` through ``registry``; ``kind`` names it in errors."""
    if name not in registry:
        hint = " (a config names classes, it does not import them)" if ":" in name else ""
        raise RegistryError(
            f"unknown {kind} {name!r}{hint}: use one of {', '.join(sorted(registry))}, "
            f"or register your own class with sb3_pm.zoo.registry.register_class({kind!r}, name, cls)"
        )
    entry = registry[name]
    return import_path(entry) if isinstance(entry, str) else entry


def register_class(key: str, name: str, cls: type) -> None:
    """Make ``name`` usable as the value of the class-valued config key ``key``
    (``activation_fn``, ``optimizer_class`` or ``features_extractor_class``) in this process.

    :raises RegistryError: for another key, a name already taken by another class, or a ``cls``
        that is not a class.
    """
    if key not in CLASS_KEYS:
        raise RegistryError(f"{key!r} is not a class-valued key: use one of {', '.join(sorted(CLASS_KEYS))}")
    if not isinstance(cls, type):
        raise RegistryError(f"register_class({key!r}, {name!r}, ...) needs a class, got {cls!r}")
    registry = CLASS_KEYS[key]
    taken = registry.get(name)
    if taken is not None and (import_path(taken) if isinstance(taken, str) else taken) is not cls:
        raise RegistryError(f"{key} {name!r} already names another class")
    registry[name] = cls  # type: ignore[assignment]  # a class given by code, not a path


def resolve_algo(name: str) -> type:
    """The algorithm class for ``name`` (``dcbf_ppo``, ``maskable_ppo`` or ``ppo``).

    :raises RegistryError: for an unknown name, or one whose module cannot be imported.
    """
    if name not in ALGORITHMS:
        raise RegistryError(f"unknown algo {name!r}: use one of {', '.join(sorted(ALGORITHMS))}")
    try:
        return import_path(ALGORITHMS[name])
    except ImportError as error:
        raise RegistryError(f"algo {name!r} is not available: {error}") from error


def algo_name(cls: type) -> str:
    """The registry name of an algorithm class (its lower-cased class name if unregistered)."""
    for name, path in ALGORITHMS.items():
        module_name, _, attr = path.partition(":")
        if cls.__name__ == attr:
            return name
    return cls.__name__.lower()


def default_algo() -> str:
    """``dcbf_ppo`` when :mod:`sb3_pm.ppo_dcbf` imports, else ``maskable_ppo``."""
    try:
        resolve_algo("dcbf_ppo")
    except RegistryError:
        return "maskable_ppo"
    return "dcbf_ppo"


def uses_masks(cls: type) -> bool:
    """True for sb3-contrib's ``MaskablePPO`` and its subclasses (they read ``action_masks``)."""
    try:
        from sb3_contrib import MaskablePPO
    except ImportError:  # pragma: no cover - sb3-contrib is a dependency
        return False
    return issubclass(cls, MaskablePPO)


def resolve_policy_kwargs(policy_kwargs: dict[str, Any] | None) -> dict[str, Any]:
    """Copy ``policy_kwargs`` with class names (``activation_fn: ReLU``) replaced by classes."""
    resolved = dict(policy_kwargs or {})
    for key, registry in CLASS_KEYS.items():
        value = resolved.get(key)
        if isinstance(value, str):
            resolved[key] = lookup(registry, value, key)
    return resolved


__all__ = [
    "ACTIVATIONS",
    "ALGORITHMS",
    "CLASS_KEYS",
    "DEFAULT_POLICIES",
    "FEATURES_EXTRACTORS",
    "OPTIMIZERS",
    "RegistryError",
    "algo_name",
    "default_algo",
    "import_path",
    "lookup",
    "register_class",
    "resolve_algo",
    "resolve_policy_kwargs",
    "uses_masks",
]
