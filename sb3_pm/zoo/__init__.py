"""rl-zoo style configuration: YAML -> keyword arguments, name -> class registries, schedules.

The YAML files themselves live in the repository's ``zoo/`` folder and install with the package
(:mod:`sb3_pm.zoo.shipped`): ``load_config("ippo", "paper-50")`` finds the default anywhere.
"""

from sb3_pm.zoo.config import ConfigError, TrainConfig, load_config, read_yaml
from sb3_pm.zoo.registry import ALGORITHMS, RegistryError, default_algo, resolve_algo, resolve_policy_kwargs
from sb3_pm.zoo.schedules import parse_schedule
from sb3_pm.zoo.shipped import DEFAULT_CONFIG, resolve_config_path, resolve_experiment_path, shipped_names

__all__ = [
    "ALGORITHMS",
    "ConfigError",
    "DEFAULT_CONFIG",
    "RegistryError",
    "TrainConfig",
    "default_algo",
    "load_config",
    "parse_schedule",
    "read_yaml",
    "resolve_algo",
    "resolve_config_path",
    "resolve_experiment_path",
    "resolve_policy_kwargs",
    "shipped_names",
]
