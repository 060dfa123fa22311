"""Networks of one learning agent: GAT encoder, state estimator, DCBF filter and the DCBF policy."""

from sb3_pm.policies.dcbf import DCBFConfig, dcbf_mask, dcbf_mask_from_map
from sb3_pm.policies.estimator import StateEstimator, transition_pairs
from sb3_pm.policies.extractor import GATFeaturesExtractor
from sb3_pm.policies.layers import GraphAttention
from sb3_pm.policies.policy import DCBFActorCriticPolicy

__all__ = [
    "DCBFActorCriticPolicy",
    "DCBFConfig",
    "GATFeaturesExtractor",
    "GraphAttention",
    "StateEstimator",
    "dcbf_mask",
    "dcbf_mask_from_map",
    "transition_pairs",
]
