"""Each agent's territory in the env: what the ``territory`` reward, ``territory_input`` and
``advice_input`` read.

:class:`EnvTerritories` is a part of :class:`~sb3_pm.envs.persistent_monitoring.PersistentMonitoringEnv`
(its base class). The territories follow the env's ``territories`` convention
(:mod:`sb3_pm.planning.conventions`): ``"split"`` is fixed per graph and set when the graph is;
``"planned"`` and ``"planned_tours"`` depend on the start positions and are set at every reset,
once the agents are placed.
Plans are cached per start positions, since a plan depends on nothing else on one graph.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sb3_pm.envs.territory_rule import TerritoryAdvice
from sb3_pm.planning.conventions import TeamTerritories, is_planned, team_territory


class EnvTerritories:
    """The territory half of the environment (see the module docstring)."""

    # Set by the environment's constructor.
    territories: str
    territory_input: bool
    advice_input: bool
    reward_weights: dict[str, float]
    n_agents: int
    max_cycles: int
    u_max: int
    graph: Any
    core: Any

    def _uses_territory(self) -> bool:
        return "territory" in self.reward_weights or self.territory_input or self.advice_input

    def _territories_for_graph(self) -> None:
        """The graph changed: forget its plans, and set the territories a split fixes now."""
        self._plans: dict[tuple[int, ...], TeamTerritories] = {}
        self._set_territory(None)
        if self._uses_territory() and self.territories == "split":
            starts = np.zeros(self.n_agents, dtype=np.int64)  # the split reads no start
            self._set_territory(team_territory("split", self.graph, starts, self.max_cycles, self.u_max))

    def _territories_for_episode(self) -> None:
        """The agents are placed: under a planned convention, plan (or recall) the groups for their starts."""
        if not self._uses_territory() or not is_planned(self.territories):
            return
        starts = tuple(int(node) for node in self.core.positions)
        if starts not in self._plans:
            self._plans[starts] = team_territory(
                self.territories, self.graph, np.asarray(starts), self.max_cycles, self.u_max
            )
        self._set_territory(self._plans[starts])

    def _set_territory(self, territories: TeamTerritories | None) -> None:
        """Set the agents' territories (``None``: none) and what derives from them."""
        #: the convention's territories this episode (``None``: none)
        self._team_territories = territories
        territory = None if territories is None else territories.territory
        #: ``(n_agents, N)`` bool, the targets of each agent's territory (``territory`` reward,
        #: ``territory_input`` or ``advice_input`` only).
        self._territory = territory
        #: ``(n_agents, N, 1)`` float32, the ``territory_input`` feature column (``None`` without it).
        self._territory_column = (
            territory[:, :, None].astype(np.float32)
            if self.territory_input and territory is not None
            else None
        )
        #: The territory rule whose next move ``advice_input`` flags (``None`` without it).
        self._advice = (
            TerritoryAdvice(territory, self.graph.routes, None, self.u_max, territories.tours)
            if self.advice_input and territories is not None
            else None
        )


__all__ = ["EnvTerritories"]
