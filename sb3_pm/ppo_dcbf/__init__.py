"""PPO with a DCBF-filtered, mental-map policy (one decentralized learner)."""

from sb3_pm.ppo_dcbf.policies import DCBFPolicy
from sb3_pm.ppo_dcbf.ppo_dcbf import DCBFPPO

__all__ = ["DCBFPPO", "DCBFPolicy"]
