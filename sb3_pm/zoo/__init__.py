"""rl-zoo style configuration: YAML -> keyword arguments, name -> class registries, schedules.

The YAML files themselves live in the top-level ``zoo/`` folder (``zoo/ippo.yml``).
"""

from sb3_pm.zoo.config import ConfigError, TrainConfig, load_config, read_yaml
from sb3_pm.zoo.registry import ALGORITHMS, RegistryError, default_algo, resolve_algo, resolve_policy_kwargs
from sb3_pm.zoo.schedules import parse_schedule

__all__ = [
    "ALGORITHMS",
    "ConfigError",
    "RegistryError",
    "TrainConfig",
    "default_algo",
    "load_config",
    "parse_schedule",
    "read_yaml",
    "resolve_algo",
    "resolve_policy_kwargs",
]
