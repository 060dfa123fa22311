"""Environments: persistent monitoring on networks.

Names load on first use, so that ``import sb3_pm`` (which registers the Gymnasium ids through
:mod:`sb3_pm.registration`) stays cheap.
"""

from __future__ import annotations

import importlib
from typing import Any

_LAZY = {
    "persistent_monitoring_v0": ("sb3_pm.envs.persistent_monitoring_v0", None),
    "FEATURES": ("sb3_pm.envs.mental_map", "FEATURES"),
    "IllegalActionError": ("sb3_pm.envs.core", "IllegalActionError"),
    "MentalMaps": ("sb3_pm.envs.mental_map", "MentalMaps"),
    "MonitoringCore": ("sb3_pm.envs.core", "MonitoringCore"),
    "PersistentMonitoringEnv": ("sb3_pm.envs.persistent_monitoring", "PersistentMonitoringEnv"),
    "SingleAgentMonitoringEnv": ("sb3_pm.envs.single_agent", "SingleAgentMonitoringEnv"),
}


def __getattr__(name: str) -> Any:
    if name not in _LAZY:
        raise AttributeError(f"module 'sb3_pm.envs' has no attribute {name!r}")
    module_name, attribute = _LAZY[name]
    module = importlib.import_module(module_name)
    return module if attribute is None else getattr(module, attribute)


__all__ = list(_LAZY)
