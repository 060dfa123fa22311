"""sb3_pm: fully decentralized, safety-aware multi-agent RL on networks, for Stable-Baselines3."""

from sb3_pm.version import __version__

__all__ = ["__version__"]
