"""Centralized planning for persistent monitoring: the best schedules the library can find, and
lower bounds no team can beat (docs/PLANNING.md)."""

from sb3_pm.planning.bound import lower_bound, priced_bound, stepwise_bound
from sb3_pm.planning.components import component_bound, target_components

__all__ = ["component_bound", "lower_bound", "priced_bound", "stepwise_bound", "target_components"]
