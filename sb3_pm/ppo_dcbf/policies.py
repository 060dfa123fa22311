"""Policy names for :class:`~sb3_pm.ppo_dcbf.DCBFPPO` (``DCBFPPO("DCBFPolicy", env)``)."""

from sb3_pm.policies.policy import DCBFActorCriticPolicy

DCBFPolicy = DCBFActorCriticPolicy

__all__ = ["DCBFPolicy"]
