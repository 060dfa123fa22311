"""Non-learning teams (METHOD.md "Baselines"), all behind the :class:`Team` interface."""

from sb3_pm.baselines.base import Team

__all__ = ["Team"]
