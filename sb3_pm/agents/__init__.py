"""Per-agent machinery: mental maps (and, with the learners, the multiplexer and the team)."""

from sb3_pm.agents.mental_map import FEATURES, MentalMaps

__all__ = ["FEATURES", "MentalMaps"]
