"""Environments: persistent monitoring on networks."""

from sb3_pm.envs import persistent_monitoring_v0
from sb3_pm.envs.core import IllegalActionError, MonitoringCore
from sb3_pm.envs.persistent_monitoring import PersistentMonitoringEnv

__all__ = ["IllegalActionError", "MonitoringCore", "PersistentMonitoringEnv", "persistent_monitoring_v0"]
