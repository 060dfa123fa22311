"""The setup the train() probes share: a default team that has trained one rollout, and its first learner."""

from __future__ import annotations

from typing import Any

import torch as th

from sb3_pm.agents.team import IndependentPPO
from sb3_pm.zoo.config import load_config


def first_learner_after_one_rollout(graph: str) -> Any:
    """A default team (seed 0, one torch thread, updates one after another) trained one rollout on
    ``graph``; returns its first learner, whose rollout buffer holds that rollout."""
    th.set_num_threads(1)
    team = IndependentPPO(graph, seed=0, concurrent_updates=False, **load_config("ippo", graph).team_kwargs())
    team.learn(500)
    return team.models[team.agents[0]]
