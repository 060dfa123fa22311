"""An env copy's state as plain values, for checkpoints (:mod:`sb3_pm.agents.training.checkpoints`).

:class:`EnvState` gives :class:`~sb3_pm.envs.persistent_monitoring.PersistentMonitoringEnv` a
``state_dict()`` / ``load_state_dict()`` pair: what changes while the env runs (the true state, the
mental maps, the metrics, the reward terms, the rule's goals, the generator, the step counters), as
arrays, numbers and the generator's ``bit_generator.state``. Everything else follows from the
env's constructor arguments, so a checkpoint rebuilds each env copy from the team's settings and
loads this state into it: nothing in the file is code.
"""

from __future__ import annotations

import copy
from typing import TYPE_CHECKING, Any

import numpy as np

from sb3_pm.errors import InputError
from sb3_pm.graphs import GraphSpec
from sb3_pm.planning.conventions import TeamTerritories, is_planned

if TYPE_CHECKING:
    from sb3_pm.envs.persistent_monitoring import PersistentMonitoringEnv

#: The env's own attributes a state keeps (sub-objects keep theirs through their own pairs).
_ENV_FIELDS = ("agents", "_step_count", "_dwell", "_active", "_last_outcome_counts")


class EnvState:
    """The ``state_dict()`` / ``load_state_dict()`` pair of the persistent-monitoring env."""

    def state_dict(self: PersistentMonitoringEnv) -> dict[str, Any]:  # type: ignore[misc]
        """Everything the env's next steps depend on beyond its constructor arguments."""
        state: dict[str, Any] = {name: copy.copy(getattr(self, name)) for name in _ENV_FIELDS}
        state["rng"] = copy.deepcopy(self._rng)
        state["observed"] = copy.copy(getattr(self, "_observed", None))
        if self.family is not None:  # this episode's graph was drawn from the family
            graph = self.graph
            state["graph"] = {
                "adjacency": graph.adjacency.copy(),
                "targets": graph.targets.copy(),
                "name": graph.name,
                "positions": None if graph.positions is None else graph.positions.copy(),
                "node_ids": None if graph.node_ids is None else list(graph.node_ids),
            }
        state["core"] = self.core.state_dict()
        state["maps"] = self.maps.state_dict()
        state["metrics"] = self.metrics.state_dict()
        state["rewards"] = self.rewards_computer.state_dict()
        state["advice"] = None if self._advice is None else self._advice.state_dict()
        # the planned territories depend on the episode's starts; a split follows from the graph
        planned = is_planned(self.territories) and self._team_territories is not None
        state["territory"] = self._team_territories.territory.copy() if planned else None
        tours = self._team_territories.tours if planned else None
        state["tours"] = None if tours is None else [None if tour is None else list(tour) for tour in tours]
        return state

    def load_state_dict(self: PersistentMonitoringEnv, state: dict[str, Any]) -> None:  # type: ignore[misc]
        """Put back a :meth:`state_dict` of an env built with the same arguments.

        :raises InputError: if the state does not fit this env.
        """
        try:
            if self.family is not None:
                saved = state["graph"]
                self._use_graph(
                    GraphSpec(
                        adjacency=np.asarray(saved["adjacency"], dtype=bool),
                        targets=np.asarray(saved["targets"], dtype=bool),
                        name=str(saved["name"]),
                        positions=saved["positions"],
                        node_ids=None if saved["node_ids"] is None else tuple(saved["node_ids"]),
                    )
                )
            if not isinstance(state["rng"], np.random.Generator):
                raise InputError("the saved env state has no generator")
            for name in _ENV_FIELDS:
                setattr(self, name, copy.copy(state[name]))
            self.agents = [str(agent) for agent in self.agents]
            self._rng = state["rng"]
            if state["observed"] is not None:
                self._observed = state["observed"]
            self.core.load_state_dict(state["core"])
            self.maps.load_state_dict(state["maps"])
            self.metrics.load_state_dict(state["metrics"])
            self.rewards_computer.load_state_dict(state["rewards"])
            if state.get("territory") is not None:
                territory = np.asarray(state["territory"], dtype=bool)
                if territory.shape != (self.n_agents, self.graph.n_nodes):
                    raise InputError(f"the saved territories have shape {territory.shape}, not this env's")
                self._set_territory(TeamTerritories(territory, self._saved_tours(state, territory)))
            if (state["advice"] is None) != (self._advice is None):
                raise InputError("the saved env state does not match the env's territory advice")
            if self._advice is not None:
                self._advice.load_state_dict(state["advice"])
        except (KeyError, TypeError, AttributeError) as error:
            raise InputError(f"the saved env state is incomplete or malformed ({error!r})") from None

    def _saved_tours(  # type: ignore[misc]
        self: PersistentMonitoringEnv, state: dict[str, Any], territory: np.ndarray
    ) -> tuple[tuple[int, ...] | None, ...]:
        """The tours of a saved state with planned territories, checked against this env's
        convention and the saved territories (a state saved before tours has none: no agent tours)."""
        tours = state.get("tours")
        if tours is None:
            if self.territories == "planned_tours":
                raise InputError(
                    "the saved env state has no tours, and this env's territories are planned_tours"
                )
            return (None,) * self.n_agents
        if len(tours) != self.n_agents:
            raise InputError(f"the saved tours are {len(tours)}, not one per agent of this env")
        walks = tuple(None if tour is None else tuple(int(node) for node in tour) for tour in tours)
        if self.territories != "planned_tours" and any(walk is not None for walk in walks):
            raise InputError(
                f"the saved env state walks tours, and this env's territories are {self.territories}"
            )
        for walk, row in zip(walks, territory):
            if walk is not None and sorted(walk) != np.flatnonzero(row).tolist():
                raise InputError("the saved tours do not order the saved territories' targets")
        return walks


__all__ = ["EnvState"]
