"""sb3_pm: fully decentralized, safety-aware multi-agent RL on networks, for Stable-Baselines3.

``import sb3_pm`` is light: the learners (and torch) load on first use of ``sb3_pm.IndependentPPO``,
``sb3_pm.DCBFPPO`` or ``sb3_pm.CentralizedPPO``.
"""

from __future__ import annotations

import importlib
from typing import Any

from sb3_pm.registration import register_envs
from sb3_pm.version import __version__

# Gymnasium ids (sb3_pm/PersistentMonitoring-paper50-v0, ...): registering them imports neither
# torch nor the env, whose module is named by a string and loaded on the first gym.make, so that
# ``import sb3_pm`` stays cheap.
register_envs()

_LAZY = {
    "IndependentPPO": "sb3_pm.agents.training.team",
    "DCBFPPO": "sb3_pm.ppo_dcbf",
    "DCBFPolicy": "sb3_pm.ppo_dcbf",
    "CentralizedPPO": "sb3_pm.sharing.centralized",
    "convert_team": "sb3_pm.agents.training.legacy_teams",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'sb3_pm' has no attribute {name!r}")


__all__ = ["CentralizedPPO", "DCBFPPO", "DCBFPolicy", "IndependentPPO", "__version__", "convert_team"]
