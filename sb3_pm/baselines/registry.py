"""Baselines by name: :data:`BASELINES` and :func:`make_team`."""

from __future__ import annotations

from typing import Any

from sb3_pm.baselines.grazing import GrazingTeam
from sb3_pm.baselines.local_greedy import LocalGreedyTeam
from sb3_pm.baselines.optimal_planner import OptimalPlannerTeam
from sb3_pm.baselines.random_walk import RandomTeam
from sb3_pm.baselines.sit_on_nodes import SitOnNodesTeam
from sb3_pm.baselines.territory_patrol import (
    PlannedPatrolTeam,
    PlannedTourPatrolTeam,
    TerritoryPatrolTeam,
)
from sb3_pm.baselines.tour_patrol import TourPatrolTeam
from sb3_pm.errors import InputError
from sb3_pm.team_interface import Team

#: Baseline name -> team class, in the order reports list them.
BASELINES: dict[str, type[Team]] = {
    cls.name: cls
    for cls in (
        RandomTeam,
        SitOnNodesTeam,
        GrazingTeam,
        LocalGreedyTeam,
        TourPatrolTeam,
        TerritoryPatrolTeam,
        PlannedPatrolTeam,
        PlannedTourPatrolTeam,
        OptimalPlannerTeam,
    )
}


def make_team(name: str, **kwargs: Any) -> Team:
    """A fresh baseline team by name.

    :param name: a key of :data:`BASELINES`.
    :param kwargs: passed to the team's constructor (e.g. ``commit=False`` for ``grazing``).
    :raises ValueError: for an unknown name.
    """
    try:
        cls = BASELINES[name]
    except KeyError:
        raise InputError(f"unknown baseline {name!r}; baselines are {', '.join(BASELINES)}") from None
    return cls(**kwargs)
