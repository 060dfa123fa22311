"""``territory_patrol``: each agent keeps to its own territory's targets (docs/METHOD.md "Baselines").

Territories are the fixed, balanced split of the targets among the agents that every agent derives
from the site and its own index (:mod:`sb3_pm.graphs.territories`); agent ``agent_i`` owns
territory ``i``. No agent reads another's state and nothing is communicated: the split is a
convention fixed before the mission, so the team is not ``omniscient``.

The rule, per agent and step, on the agent's own view, is
:func:`sb3_pm.envs.territory_rule.territory_move`, each agent's goal kept step to step by
:class:`~sb3_pm.envs.territory_rule.TerritoryAdvice` (the env's ``advice_input`` flags the same
move in a learned agent's observation): dwell on one of its targets while its observed ``u`` is
positive, else head for the goal chosen earlier, else for its territory's most stale target by its
own map. An agent with no territory (fewer targets than agents) acts as ``local_greedy`` does.

Without a teammate's territory in its rule, an agent leaves a failed teammate's targets to nobody.

``planned_patrol`` (:class:`PlannedPatrolTeam`) is the same rule on the territories of the
``"planned"`` convention (:mod:`sb3_pm.planning.conventions`): the groups of the centralized plan
for the episode's start positions, which every agent computes alike from where every agent
starts, before the first move. It reads the starts, never another agent's state or an
uncertainty, and nothing is communicated while it acts; targets the plan leaves out are patrolled
by nobody.

``planned_tour_patrol`` (:class:`PlannedTourPatrolTeam`) plays the ``"planned_tours"`` convention:
the plan may walk a group of three or more targets as a tour, and the agent then takes its tour's
next target instead of the stalest.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sb3_pm.baselines._common import env_graph
from sb3_pm.baselines.local_greedy import LocalGreedyTeam
from sb3_pm.envs.mental_map import AGE, U
from sb3_pm.envs.territory_rule import TerritoryAdvice
from sb3_pm.errors import InputError
from sb3_pm.planning.conventions import TeamTerritories, team_territory
from sb3_pm.team_interface import Observation, Team


class TerritoryPatrolTeam(Team):
    """Each agent patrols the targets of its own territory, most stale first; decentralized."""

    name = "territory_patrol"
    omniscient = False
    #: the territory convention (:mod:`sb3_pm.planning.conventions`)
    convention = "split"

    def __init__(self) -> None:
        self._fallback = LocalGreedyTeam()
        #: ``(graph fingerprint, team size or starts)`` -> ``(n_agents, N)`` territories: a split
        #: depends on the site and team size alone, a plan on the starts too, so each is computed
        #: once (as ``tour_patrol`` caches its tour, and the env its plans).
        self._territories: dict[tuple[str, Any], TeamTerritories] = {}

    def reset(self, env: Any, seed: int | None = None) -> None:
        super().reset(env, seed)
        self._fallback.reset(env, seed)
        graph = env_graph(env)
        agents = list(env.unwrapped.possible_agents)
        territories = self._territory(env, graph, len(agents))
        #: The rule, with each agent's goal kept between steps (the env's advice_input runs the same).
        self.rule = TerritoryAdvice(
            territories.territory, graph.routes, None, env.unwrapped.u_max, territories.tours
        )
        self._index = {agent: i for i, agent in enumerate(agents)}

    def _territory(self, env: Any, graph: Any, n_agents: int) -> TeamTerritories:
        """Each agent's territory by :attr:`convention`."""
        state = env.unwrapped
        starts = state.positions
        key = (graph.fingerprint, n_agents if self.convention == "split" else tuple(starts.tolist()))
        if key not in self._territories:
            self._territories[key] = team_territory(
                self.convention, graph, starts, state.max_cycles, state.u_max
            )
        return self._territories[key]

    def act(self, agent: str, obs: Observation) -> int:
        """One agent's destination from its own observation."""
        if "nodes" not in obs:
            raise InputError(
                "territory_patrol needs mental-map observations: create the env with observation='map'"
            )
        i = self._index[agent]
        if self.rule.own[i].size == 0:
            return self._fallback.act(agent, obs)
        nodes = np.asarray(obs["nodes"])
        return self.rule.move(i, int(obs["position"]), nodes[:, U], nodes[:, AGE])

    def predict_dict(
        self, observations: dict[str, Observation], deterministic: bool = True
    ) -> dict[str, int]:
        return {agent: self.act(agent, obs) for agent, obs in observations.items()}


class PlannedPatrolTeam(TerritoryPatrolTeam):
    """The territory rule on the plan's groups for the episode's starts (module docstring)."""

    name = "planned_patrol"
    omniscient = False
    convention = "planned"


class PlannedTourPatrolTeam(TerritoryPatrolTeam):
    """The territory rule on the plan's groups for the episode's starts, each group the plan walks
    as a tour walked so (module docstring)."""

    name = "planned_tour_patrol"
    omniscient = False
    convention = "planned_tours"
