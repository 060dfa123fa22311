"""Territory conventions: which targets each agent of a team patrols (docs/PLANNING.md "Planned
territories").

A convention is fixed before the mission and computed by every agent alike, so it needs no
communication while the team acts:

* ``"split"``: the balanced split of the targets by hop distance
  (:func:`sb3_pm.graphs.territories.territory_nodes`), from the site and the team size alone. Agent
  ``i`` owns the territory with the ``i``-th lowest target node.
* ``"planned"``: the groups of the centralized plan (:func:`sb3_pm.planning.planner.plan_patrol`)
  for the episode's start positions. It reads where every agent starts (a pre-mission broadcast, as
  a launch plan would give it) but no uncertainty, since no agent has observed any yet: it plans as
  if every target started at 0. A target no group holds is left to nobody. The search is seeded and
  its restarts are counted, so every agent derives the same groups from the same starts. Every
  agent plays its group by the territory rule, which takes the stalest target next, so the plan
  prices every group by that rule alone: a group the plan would price by the ``tour`` rule is
  walked otherwise by the rule, and can cost far more than the plan assumed.
* ``"planned_tours"``: the same plan, free to price each group of three or more targets by the
  ``tour`` rule too (:func:`~sb3_pm.planning.group_patrol.tour_move`). An agent whose group the
  plan walks as a tour gets the tour's order with its group, and the territory rule then takes the
  tour's next target instead of the stalest (:func:`sb3_pm.envs.territory_rule.territory_move`).
  The groups are searched both ways, free to take tours and by the stalest rule alone, and the
  lower prediction is kept (the tours' search first on a tie), as ``optimal_planner`` does
  (:func:`~sb3_pm.planning.planner.plan_both_ways`): the two searches land in other local optima,
  and the one free to take tours is not always lower.

A convention gives a :class:`TeamTerritories`: each agent's targets, and the tour order of those
that walk one.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import numpy as np

from sb3_pm.errors import InputError
from sb3_pm.graphs import GraphSpec
from sb3_pm.graphs.routes import Routes
from sb3_pm.graphs.territories import site_territory_nodes
from sb3_pm.planning.planner import plan_both_ways, plan_patrol

__all__ = [
    "PLAN_RESTARTS",
    "TERRITORY_CONVENTIONS",
    "TeamTerritories",
    "check_convention",
    "is_planned",
    "planned_territory",
    "sweep_targets",
    "team_territory",
]

#: The conventions by name.
TERRITORY_CONVENTIONS = ("split", "planned", "planned_tours")
#: The planned convention's perturbed restarts of the local search.
PLAN_RESTARTS = 20
#: A wall-clock cap on one search of a plan, in seconds (``planned_tours`` runs two), so that a huge
#: site cannot stall a reset; reaching it would make the groups depend on the machine's speed, and
#: on the published graphs and families a plan takes seconds.
PLAN_SECONDS = 600.0


@dataclass(frozen=True, eq=False)  # an array field: no generated comparison
class TeamTerritories:
    """Each agent's territory by a convention.

    :ivar territory: ``(n_agents, N)`` bool, ``[i, v]`` True when target ``v`` is agent ``i``'s.
    :ivar tours: per agent, its targets in tour order where it walks them as a tour, else ``None``
        (the stalest target next).
    """

    territory: np.ndarray
    tours: tuple[tuple[int, ...] | None, ...]

    @classmethod
    def stalest(cls, territory: np.ndarray) -> TeamTerritories:
        """Territories every agent walks stalest first."""
        return cls(territory, (None,) * territory.shape[0])


def check_convention(name: object) -> str:
    """``name`` if it is a convention, else a one-line :class:`InputError`."""
    if name not in TERRITORY_CONVENTIONS:
        raise InputError(f"territories must be one of {TERRITORY_CONVENTIONS}, got {name!r}")
    return str(name)


def is_planned(name: str) -> bool:
    """Whether convention ``name`` plans per episode from the start positions."""
    return name in ("planned", "planned_tours")


def planned_territory(
    graph: GraphSpec, starts: np.ndarray, max_cycles: int, u_max: int, tours: bool = False
) -> TeamTerritories:
    """The groups the plan gives the agents from these starts (``starts``: ``(n_agents,)`` nodes);
    with ``tours``, the plan may walk a group of three or more targets as a tour (the lower of the
    two searches of the module docstring)."""
    starts = np.asarray(starts, dtype=np.int64)
    search = plan_both_ways if tours else partial(plan_patrol, tour_groups=False)
    plan = search(graph, starts, max_cycles, u_max, search_seconds=PLAN_SECONDS, restarts=PLAN_RESTARTS)
    territory = np.zeros((starts.size, graph.n_nodes), dtype=bool)
    for agent, group in enumerate(plan.groups):
        territory[agent, list(group)] = True
    walks = tuple(
        tuple(int(node) for node in group) if rule == "tour" else None
        for group, rule in zip(plan.groups, plan.rules)
    )
    return TeamTerritories(territory, walks)


def team_territory(
    convention: str, graph: GraphSpec, starts: np.ndarray, max_cycles: int, u_max: int
) -> TeamTerritories:
    """Each agent's territory by ``convention`` (``starts``: ``(n_agents,)`` nodes)."""
    if is_planned(check_convention(convention)):
        return planned_territory(graph, starts, max_cycles, u_max, tours=convention == "planned_tours")
    n_agents = int(np.asarray(starts).size)
    return TeamTerritories.stalest(site_territory_nodes(graph, n_agents))


def sweep_targets(
    territory: np.ndarray, target_indices: np.ndarray, routes: Routes, starts: np.ndarray
) -> np.ndarray:
    """The targets no territory holds, each handed to one agent to sweep (the filter's rule 12,
    :mod:`sb3_pm.policies.visit_deadline`): to the agent whose territory comes nearest to it in
    hops, or whose start does where its territory is empty; ties to the lower agent index. Every
    agent computes the same from the agreed territories and starts, so it needs no communication.

    :param territory: ``(n_agents, N)`` bool, each agent's territory.
    :param target_indices: ``(T,)`` the site's target nodes.
    :param routes: the site's distances to its targets (``graph.routes``), read only where some
        target has no territory.
    :param starts: ``(n_agents,)`` each agent's start node.
    :return: ``(n_agents, N)`` bool, True on the targets agent ``i`` sweeps.
    """
    territory = np.asarray(territory, dtype=bool)
    targets = np.asarray(target_indices, dtype=np.int64)
    swept = np.zeros_like(territory)
    dropped = np.flatnonzero(~territory[:, targets].any(0))  # columns of targets nobody holds
    if dropped.size == 0:
        return swept
    # (n_agents, k): hops from each agent's nearest territory node (or its start) to each dropped target
    reach = np.stack(
        [
            routes.to_targets(np.flatnonzero(row) if row.any() else np.asarray([start]))[:, dropped].min(0)
            for row, start in zip(territory, np.asarray(starts, dtype=np.int64))
        ]
    )
    swept[reach.argmin(0), targets[dropped]] = True  # argmin: the first (lowest) agent on a tie
    return swept
