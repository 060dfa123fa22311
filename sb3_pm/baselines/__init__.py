"""Non-learning teams (docs/METHOD.md "Baselines"), all behind the
:class:`~sb3_pm.team_interface.Team` interface (re-exported here as ``Team``).

``make_team("grazing")`` builds one by name; :data:`BASELINES` lists them.
"""

from sb3_pm.baselines.grazing import GrazingTeam
from sb3_pm.baselines.local_greedy import LocalGreedyTeam
from sb3_pm.baselines.random_walk import RandomTeam
from sb3_pm.baselines.registry import BASELINES, make_team
from sb3_pm.baselines.sit_on_nodes import SitOnNodesTeam
from sb3_pm.baselines.territory_patrol import (
    PlannedPatrolTeam,
    PlannedTourPatrolTeam,
    TerritoryPatrolTeam,
)
from sb3_pm.baselines.tour_patrol import TourPatrolTeam, approximate_tour
from sb3_pm.team_interface import Team

__all__ = [
    "BASELINES",
    "GrazingTeam",
    "LocalGreedyTeam",
    "PlannedPatrolTeam",
    "PlannedTourPatrolTeam",
    "RandomTeam",
    "SitOnNodesTeam",
    "Team",
    "TerritoryPatrolTeam",
    "TourPatrolTeam",
    "approximate_tour",
    "make_team",
]
