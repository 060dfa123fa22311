"""Mental maps (docs/METHOD.md "Mental map", paper §III.B), one per agent, in pure NumPy.

A mental map is an agent's fixed-size memory of the whole graph built only from what that agent
has observed itself. The class is batched over agents because the environment updates every map
each step; each row is still one agent's private memory and no row ever reads another.

Node features, one row per node (``FEATURES`` gives the column order):

========  ==============================================================
u         last observed uncertainty (0 until observed)
age       steps since the node was last observed (grows from 0 at episode start)
target    target flag (0 until observed)
occupied  another agent was on the node when last observed
self      the node is the agent's own position
========  ==============================================================

Known adjacency: with ``graph_knowledge="discovered"`` (the paper's), an edge is added the first
time it is observed. An agent observes the edges incident to the nodes strictly inside its
observation ball (within ``obs_radius - 1`` hops), so with radius 1 it learns the edges at its own
node. With ``"known"`` the whole topology is given up front. Node features reset every episode;
discovered edges persist for the map's lifetime, since the graph is static.

Known targets: with ``target_knowledge="discovered"`` (the paper's), the target flag of a node is 0
until the agent observes the node, every episode. With ``"known"`` every map starts each episode
with the true target flags, as a monitoring mission's map would list its sites; the uncertainty
and age of a target are still only what the agent itself has observed.
"""

from __future__ import annotations

import copy
from typing import Any, cast

import numpy as np

from sb3_pm.envs.known_edges import LAYOUTS, KnownEdges
from sb3_pm.errors import InputError

FEATURES = ("u", "age", "target", "occupied", "self")
U, AGE, TARGET, OCCUPIED, SELF = range(len(FEATURES))
GRAPH_KNOWLEDGE = ("discovered", "known")
TARGET_KNOWLEDGE = ("discovered", "known")


class MentalMaps:
    """The mental maps of ``n_agents`` agents on an ``n_nodes``-node graph.

    :param n_agents: number of maps.
    :param adjacency: ``(N, N)`` bool true adjacency; the maps read from it only rows that their
        agent observes (or all of it with ``graph_knowledge="known"``).
    :param graph_knowledge: ``"discovered"`` or ``"known"``.
    :param target_knowledge: ``"discovered"`` or ``"known"`` (then ``targets`` is required).
    :param targets: ``(N,)`` bool true target flags, read only with ``target_knowledge="known"``.
    :param layout: ``"dense"``: the known adjacency is :attr:`adjacency` ``(n_agents, N, N)``;
        ``"edges"``: it is :attr:`known_edges` (:class:`~sb3_pm.envs.known_edges.KnownEdges`,
        ``(n_agents, E)`` over the graph's edge list) and :attr:`adjacency` is ``None``.
    """

    def __init__(
        self,
        n_agents: int,
        adjacency: np.ndarray,
        graph_knowledge: str = "discovered",
        target_knowledge: str = "discovered",
        targets: np.ndarray | None = None,
        layout: str = "dense",
    ) -> None:
        if layout not in LAYOUTS:
            raise InputError(f"layout must be one of {LAYOUTS}, got {layout!r}")
        if graph_knowledge not in GRAPH_KNOWLEDGE:
            raise InputError(f"graph_knowledge must be one of {GRAPH_KNOWLEDGE}, got {graph_knowledge!r}")
        if target_knowledge not in TARGET_KNOWLEDGE:
            raise InputError(f"target_knowledge must be one of {TARGET_KNOWLEDGE}, got {target_knowledge!r}")
        if target_knowledge == "known" and targets is None:
            raise InputError("target_knowledge='known' needs the graph's target flags (targets=...)")
        self.n_agents = n_agents
        self.n_nodes = adjacency.shape[0]
        self.graph_knowledge = graph_knowledge
        self.target_knowledge = target_knowledge
        #: ``(N,)`` float32 target flags every map starts an episode with (``None``: none known).
        self._known_targets = (
            np.asarray(targets, dtype=np.float32).reshape(-1) if target_knowledge == "known" else None
        )
        self._true_adjacency = np.asarray(adjacency, dtype=bool)
        # One contiguous ``(n_agents, N)`` float32 array per feature: the per-step updates run on
        # contiguous memory, and :attr:`features` stacks them only when an observation is made.
        self.channels = np.zeros((len(FEATURES), n_agents, self.n_nodes), dtype=np.float32)
        self.layout = layout
        #: ``(n_agents, N, N)`` bool known adjacency (``layout="dense"``; ``None`` otherwise).
        self.adjacency: np.ndarray | None = None
        #: The known edges over the graph's edge list (``layout="edges"``; ``None`` otherwise).
        self.known_edges: KnownEdges | None = None
        if layout == "dense":
            self.adjacency = np.zeros((n_agents, self.n_nodes, self.n_nodes), dtype=bool)
        else:
            self.known_edges = KnownEdges(n_agents, self._true_adjacency, graph_knowledge == "known")
        #: ``(n_agents, N)`` bool: nodes whose incident edges the agent has observed.
        self.explored = np.zeros((n_agents, self.n_nodes), dtype=bool)
        #: ``(n_agents,)`` running sum, this episode, of the map's uncertainties (reward term ``change``).
        self.episode_uncertainty_sum = np.zeros(n_agents, dtype=np.float64)
        self._adjacency_int8: list[np.ndarray | None] = [None] * n_agents
        #: True while every entry of ``_adjacency_int8`` is built (no map gained an edge since).
        self._adjacency_cached = False
        #: Per map, the positions whose whole edge-node row has been folded into ``explored``: a
        #: map standing on one of them again can discover nothing (``explored`` only grows).
        self._folded_positions: list[set[int]] = [set() for _ in range(n_agents)]
        self._rows = np.arange(n_agents)
        self._all_explored = False
        # Staging block for the four channels overwritten on observation (U, AGE, TARGET, OCCUPIED
        # are adjacent), so one masked copy updates them all; AGE's source is always 0.
        self._observed_values = np.zeros((OCCUPIED + 1, n_agents, self.n_nodes), dtype=np.float32)
        self._targets_staged = False
        #: Keep :attr:`episode_uncertainty_sum` up to date (only the ``change`` reward needs it).
        self.track_uncertainty_sum = True
        if graph_knowledge == "known":
            if self.adjacency is not None:
                self.adjacency[:] = self._true_adjacency
            self.explored[:] = True
            self._all_explored = True

    def __setstate__(self, state: dict) -> None:
        """Unpickle (a copy of the env): NumPy unpickles every array writeable, so the cached int8
        adjacencies are marked read-only again, as :meth:`adjacency_observation` promises."""
        self.__dict__.update(state)
        for cached in state.get("_adjacency_int8", []):
            if cached is not None:
                cached.setflags(write=False)

    #: What :meth:`state_dict` keeps: the maps, what they discovered, and the staging the next
    #: update starts from (the int8 adjacency cache is derived, and rebuilt on demand).
    _STATE = (
        "channels",
        "adjacency",
        "explored",
        "episode_uncertainty_sum",
        "_folded_positions",
        "_all_explored",
        "_observed_values",
        "_targets_staged",
        "track_uncertainty_sum",
    )

    def state_dict(self) -> dict[str, Any]:
        """The maps as plain values (a checkpoint's); in the edges layout ``adjacency`` is ``None``
        and ``known_edges`` holds the ``(n_agents, E)`` bool known edges."""
        state = {name: copy.deepcopy(getattr(self, name)) for name in self._STATE}
        if self.known_edges is not None:
            state["known_edges"] = self.known_edges.known.copy()
        return state

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Put back a :meth:`state_dict` of maps of the same size and layout."""
        if (state["adjacency"] is None) != (self.known_edges is not None):
            raise InputError("the saved mental maps are of another layout than the env's")
        for name in self._STATE:
            setattr(self, name, copy.deepcopy(state[name]))
        if self.channels.shape != (len(FEATURES), self.n_agents, self.n_nodes):
            raise InputError("the saved mental maps do not match the env (other team size or graph)")
        if self.known_edges is not None:
            known = np.asarray(state["known_edges"])
            if known.shape != self.known_edges.known.shape:
                raise InputError("the saved mental maps do not match the env (other team size or graph)")
            self.known_edges.load(known)
        self._folded_positions = [set(folded) for folded in self._folded_positions]
        self._adjacency_int8 = [None] * self.n_agents
        self._adjacency_cached = False

    def forget_edges(self) -> None:
        """Start the known adjacency over (a new agent lifetime); no-op in ``"known"`` mode."""
        if self.graph_knowledge == "discovered":
            if self.adjacency is not None:
                self.adjacency[:] = False
            if self.known_edges is not None:
                self.known_edges.forget()
            self.explored[:] = False
            self._all_explored = False
            self._adjacency_int8 = [None] * self.n_agents
            self._adjacency_cached = False
            self._folded_positions = [set() for _ in range(self.n_agents)]

    @property
    def features(self) -> np.ndarray:
        """``(n_agents, N, F)`` float32 node features, a fresh array (columns in :data:`FEATURES` order)."""
        return self.channels.transpose(1, 2, 0).copy()

    def reset_features(self) -> None:
        """Start a new episode: clear node features (edges are kept; known targets stay flagged)."""
        self.channels[:] = 0.0
        if self._known_targets is not None:
            self.channels[TARGET] = self._known_targets  # broadcast over the agents
        self.episode_uncertainty_sum[:] = 0.0

    def update(
        self,
        positions: np.ndarray,
        observed: np.ndarray,
        uncertainty: np.ndarray,
        targets: np.ndarray,
        counts: np.ndarray,
        edge_nodes: np.ndarray,
        advance_age: bool = True,
        edge_positions: list[int] | None = None,
        presence: np.ndarray | None = None,
    ) -> None:
        """Fold one step of local observations into every map.

        :param positions: ``(n_agents,)`` int node of each agent.
        :param observed: ``(n_agents, N)`` bool, nodes each agent observes now.
        :param uncertainty: ``(N,)`` true uncertainties; only observed entries are read.
        :param targets: ``(N,)`` true target flags; only observed entries are read.
        :param counts: ``(N,)`` agents per node; each map sees others' presence on observed nodes.
        :param edge_nodes: ``(n_agents, N)`` bool, nodes whose incident edges each agent observes now.
        :param advance_age: False for the very first observation of an episode.
        :param edge_positions: the agents' nodes, when each row of ``edge_nodes`` is exactly the
            edge-node row of its agent's node (no failed agent, no shared map): then a map on a
            node whose row it has folded before is skipped without any array work.
        :param presence: ``(N,)`` bool, ``counts > 0``, if the caller has it (saves recomputing it).
        """
        c = self.channels
        self_onehot = c[SELF]
        self_onehot.fill(0.0)
        self_onehot[self._rows, positions] = 1.0
        if advance_age:
            c[AGE] += 1.0
        staged = self._observed_values  # AGE's row stays 0; TARGET's row is constant for a graph
        staged[U] = uncertainty
        if not self._targets_staged:
            staged[TARGET] = targets
            self._targets_staged = True
        # Others there: count minus self > 0, i.e. count > 0 off the agent's own node and count > 1
        # on it (cheaper than comparing the int counts with the float one-hot row by row).
        occupied = staged[OCCUPIED]
        if presence is None:
            np.greater(counts, 0, out=occupied)
        else:
            np.copyto(occupied, presence)  # the bool broadcast cast to 0/1, cheaper than comparing
        occupied[self._rows, positions] = counts[positions] > 1
        c[: OCCUPIED + 1] = np.where(observed, staged, c[: OCCUPIED + 1])  # faster than a masked copyto here
        if self.track_uncertainty_sum:
            self.episode_uncertainty_sum += np.add.reduce(c[U], axis=1)  # = .sum(axis=1), no wrapper
        if not self._all_explored:
            self._discover_edges(edge_nodes, edge_positions)

    def _discover_edges(self, edge_nodes: np.ndarray, edge_positions: list[int] | None = None) -> None:
        folded = self._folded_positions
        if edge_positions is not None:
            if all(position in seen for position, seen in zip(edge_positions, folded)):
                return  # the common case once the agents walk where they have been
            for position, seen in zip(edge_positions, folded):
                seen.add(position)  # folded by the lines below
        new = edge_nodes & ~self.explored
        if not new.any():
            return
        for agent in np.flatnonzero(new.any(axis=1)):
            rows = np.flatnonzero(new[agent])
            if self.known_edges is not None:
                self.known_edges.discover(agent, rows)
            else:
                assert self.adjacency is not None
                self.adjacency[agent, rows, :] |= self._true_adjacency[rows, :]
                self.adjacency[agent, :, rows] |= self._true_adjacency[rows, :]
            self.explored[agent, rows] = True
            self._adjacency_int8[agent] = None
        self._adjacency_cached = False
        self._all_explored = bool(self.explored.all())

    def adjacency_observation(self, agent: int) -> np.ndarray:
        """``(N, N)`` int8 read-only known adjacency of ``agent``.

        The array is rebuilt only when the map gains an edge, and never written afterwards, so a
        caller may keep it as long as it likes without copying.
        """
        cached = self._adjacency_int8[agent]
        if cached is None:
            assert self.adjacency is not None, "the edges layout has no dense adjacency"
            cached = self.adjacency[agent].astype(np.int8)
            cached.setflags(write=False)
            self._adjacency_int8[agent] = cached
        return cached

    def adjacency_observations(self) -> list[np.ndarray]:
        """Every map's :meth:`adjacency_observation` (``n_agents`` read-only ``(N, N)`` int8
        arrays), in agent order."""
        if self._adjacency_cached:  # the common case: no map gained an edge
            return cast(list[np.ndarray], list(self._adjacency_int8))
        arrays = [self.adjacency_observation(i) for i in range(self.n_agents)]
        self._adjacency_cached = True
        return arrays
