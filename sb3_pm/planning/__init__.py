"""Centralized planning for persistent monitoring: the best schedules the library can find, and
lower bounds no team can beat (docs/PLANNING.md)."""

from sb3_pm.planning.bound import lower_bound, priced_bound, stepwise_bound

__all__ = ["lower_bound", "priced_bound", "stepwise_bound"]
