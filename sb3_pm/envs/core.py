"""Persistent-monitoring dynamics in pure NumPy (docs/METHOD.md "Dynamics"; the paper's eq. 1 with a cap).

The core knows nothing of PettingZoo, observations or rewards: it holds the true state (agent
positions and node uncertainties) and advances it one simultaneous move at a time. Everything is
vectorized over agents and targets; nothing here touches networkx.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sb3_pm.errors import InputError
from sb3_pm.graphs import GraphSpec

#: The default cap on a target's uncertainty (``u_max``), here and in the PettingZoo env.
DEFAULT_U_MAX = 100


class IllegalActionError(InputError):
    """An agent asked to move to a node outside its reachable set."""


@dataclass(slots=True)
class StepOutcome:
    """What one simultaneous move did; all arrays are fresh (safe to keep).

    :ivar counts: ``(N,)`` int, how many agents stand on each node after the move.
    :ivar presence: ``(N,)`` bool, ``counts > 0``.
    :ivar u_before: ``(n_agents,)`` int, the uncertainty each agent found at its new node before the
        update (what its presence acted on).
    :ivar u_after: ``(n_agents,)`` int, the uncertainty at each agent's node after the update.
    :ivar collided: ``(n_agents,)`` bool, the agent shares its node with another agent.
    :ivar illegal: ``(n_agents,)`` bool, the agent's request was illegal and replaced by staying.
    :ivar any_illegal: ``illegal.any()``, precomputed.
    :ivar target_presence: ``(T,)`` bool, ``presence`` on the targets (``graph.target_indices`` order).
    :ivar target_uncertainty: ``(T,)`` int, the targets' uncertainties after the update.
    """

    counts: np.ndarray
    presence: np.ndarray
    u_before: np.ndarray
    u_after: np.ndarray
    collided: np.ndarray
    illegal: np.ndarray
    any_illegal: bool
    target_presence: np.ndarray
    target_uncertainty: np.ndarray


class MonitoringCore:
    """The true state of one persistent-monitoring episode.

    :param graph: the graph to monitor.
    :param n_agents: team size, ``1 <= n_agents <= N``.
    :param u_max: the uncertainty cap.
    """

    def __init__(self, graph: GraphSpec, n_agents: int, u_max: int = DEFAULT_U_MAX) -> None:
        if n_agents < 1:
            raise InputError(f"n_agents must be at least 1, got {n_agents}")
        if n_agents > graph.n_nodes:
            raise InputError(f"more agents ({n_agents}) than nodes ({graph.n_nodes}) in graph {graph.name!r}")
        if u_max < 1:
            raise InputError(f"u_max must be a positive integer, got {u_max}")
        self.graph = graph
        self.n_agents = n_agents
        self.u_max = int(u_max)
        self._target_idx = graph.target_indices
        self._build_tables()
        self.positions = np.zeros(n_agents, dtype=np.int64)
        #: ``(N,)`` int64, every value in ``[0, u_max]`` (set it through :meth:`reset`): :meth:`step`
        #: indexes its update table with it.
        self.uncertainty = np.zeros(graph.n_nodes, dtype=np.int64)

    def _build_tables(self) -> None:
        """The lookup tables of :meth:`step`, derived from the graph and ``u_max``.

        * ``_legal_sets``: each node's reachable set as a frozenset of ints. A team of a few agents
          checks its moves with a few set lookups, far cheaper than any NumPy call; a destination
          outside ``0..N-1`` is simply in no set.
        * ``_next_u``: eq. (1) with the cap as one ``(2 * (u_max + 1),)`` int64 table, indexed by
          ``u + (u_max + 1) * occupied``: one gather updates every target.
        """
        #: ``N``, a plain attribute: the per-step code reads it where a property call would cost more.
        self.n_nodes = self.graph.n_nodes
        # From the adjacency's rows, not ``graph.reachable``: no (N, N) table is built for a core.
        self._legal_sets = [
            frozenset(np.flatnonzero(row).tolist()) | {node} for node, row in enumerate(self.graph.adjacency)
        ]
        levels = np.arange(self.u_max + 1, dtype=np.int64)
        # empty: u + 1 up to the cap; occupied: u - 1, and 0 stays 0
        self._next_u = np.concatenate([np.minimum(levels + 1, self.u_max), np.maximum(levels - 1, 0)])

    def state_dict(self) -> dict[str, np.ndarray]:
        """The true state (positions and uncertainties), as plain arrays (a checkpoint's)."""
        return {"positions": self.positions.copy(), "uncertainty": self.uncertainty.copy()}

    def load_state_dict(self, state: dict[str, np.ndarray]) -> None:
        """Put back a :meth:`state_dict` of a core on the same graph."""
        self.positions = np.asarray(state["positions"], dtype=np.int64).copy()
        self.uncertainty = np.asarray(state["uncertainty"], dtype=np.int64).copy()
        if self.positions.shape != (self.n_agents,) or self.uncertainty.shape != (self.n_nodes,):
            raise InputError("the saved env state does not match the env (other team size or graph)")

    def reset(self, positions: np.ndarray, uncertainty: np.ndarray | None = None) -> None:
        """Place the agents and set the initial uncertainties (zeros by default; non-targets stay 0)."""
        positions = np.asarray(positions, dtype=np.int64)
        if positions.shape != (self.n_agents,):
            raise InputError(f"expected {self.n_agents} initial positions, got {positions.tolist()}")
        if ((positions < 0) | (positions >= self.graph.n_nodes)).any():
            raise InputError(
                f"initial positions {positions.tolist()} are not all nodes of 0..{self.graph.n_nodes - 1}"
            )
        self.positions = positions.copy()
        self.uncertainty = np.zeros(self.graph.n_nodes, dtype=np.int64)
        if uncertainty is not None:
            values = np.asarray(uncertainty, dtype=np.int64)
            if values.shape != (self.graph.n_nodes,) or (values < 0).any() or (values > self.u_max).any():
                raise InputError(
                    f"initial uncertainty must be {self.graph.n_nodes} integers in [0, {self.u_max}]"
                )
            self.uncertainty[self._target_idx] = values[self._target_idx]

    def reachable_from(self, agent: int) -> np.ndarray:
        """Node indices agent ``agent`` may move to now (its node and its neighbours)."""
        return np.array(sorted(self._legal_sets[int(self.positions[agent])]), dtype=np.int64)

    def step(
        self,
        destinations: np.ndarray,
        illegal: str = "raise",
        agent_names: list[str] | None = None,
        active: np.ndarray | None = None,
    ) -> StepOutcome:
        """Move every agent at once, then update uncertainties (eq. 1 and the cap).

        :param destinations: ``(n_agents,)`` node indices.
        :param illegal: ``"raise"`` raises :class:`IllegalActionError` for a move outside the reachable
            set; ``"stay"`` keeps such an agent in place and flags it in the outcome.
        :param agent_names: names used in error messages.
        :param active: ``(n_agents,)`` bool, the agents still in the team (``None``: all). A failed
            agent stays where it is and is on no node: it clears nothing and collides with nobody.
        """
        destinations = np.asarray(destinations, dtype=np.int64)
        if destinations.shape != (self.n_agents,):  # the set check below would zip a short list
            raise InputError(f"expected {self.n_agents} destinations, got shape {destinations.shape}")
        if active is not None:
            destinations = np.where(active, destinations, self.positions)
        n = self.n_nodes
        legal_sets = self._legal_sets
        # A few agents: set lookups on Python ints beat any vectorized check.
        legal = [
            destination in legal_sets[position]
            for position, destination in zip(self.positions.tolist(), destinations.tolist())
        ]
        all_legal = all(legal)
        illegal_flags = np.zeros(self.n_agents, dtype=bool) if all_legal else ~np.array(legal, dtype=bool)
        if not all_legal:
            if illegal == "raise":
                agent = legal.index(False)
                name = agent_names[agent] if agent_names else f"agent {agent}"
                raise IllegalActionError(
                    f"{name} on node {int(self.positions[agent])} "
                    f"cannot move to node {int(destinations[agent])}; "
                    f"its reachable set is {self.reachable_from(agent).tolist()}"
                )
            destinations = np.where(illegal_flags, self.positions, destinations)
        self.positions = destinations
        present = destinations if active is None else destinations[active]
        counts = np.bincount(present, minlength=n)
        presence = counts > 0
        uncertainty = self.uncertainty
        u_before = uncertainty[destinations]
        targets = self._target_idx
        target_presence = presence[targets]
        # eq. 1 with the cap, by table (see _build_tables): a visited target drops by one or
        # stays at zero; an unvisited one grows by one up to u_max.
        u = self._next_u[uncertainty[targets] + target_presence * (self.u_max + 1)]
        uncertainty[targets] = u
        collided = counts[destinations] > 1
        return StepOutcome(
            counts=counts,
            presence=presence,
            u_before=u_before,
            u_after=uncertainty[destinations],
            collided=collided if active is None else collided & active,
            illegal=illegal_flags,
            any_illegal=not all_legal,
            target_presence=target_presence,
            target_uncertainty=u,
        )
