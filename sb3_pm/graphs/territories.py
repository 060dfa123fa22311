"""Territories: a fixed, balanced split of a graph's targets among ``K`` agents.

A team of independent learners settles, when it settles at all, on one learner per group of nearby
targets (research/LOG.md 3h, "Where the agents settle"); the runs that fail are those in which two
learners contest the same group. A territory is a convention that can be agreed before the mission
from the site alone (its road network and its list of targets) and the agents' indices: no
communication is needed to compute it, and every agent computes the same one. The ``territory``
reward term (:mod:`sb3_pm.envs.rewards`) pays an agent for clearing the targets of its own territory.

The split is a capacity-constrained k-medoids over hop distances, deterministic for a given graph
and ``K``:

1. initial medoids by farthest-point selection among the targets (the first is the target with the
   largest summed distance to the others; ties go to the lower node index);
2. each target goes to a territory by a min-cost assignment (``scipy.optimize.linear_sum_assignment``)
   in which every territory holds at least ``floor(T / K)`` and at most ``ceil(T / K)`` targets,
   the cost being the hop distance to the territory's medoid;
3. each medoid moves to the member with the smallest summed distance to its members; repeat 2-3
   until nothing changes.

Territories are then ordered by their lowest target node: agent ``i`` owns territory ``i``. With
fewer targets than agents the last agents own none.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import linear_sum_assignment

from sb3_pm.graphs.spec import GraphError, GraphSpec

_MAX_ROUNDS = 50
_FORBIDDEN = 1e9
#: Subtracted from the cost of each territory's first ``floor(T / K)`` slots, so that every optimal
#: assignment fills them: larger than any sum of hop distances.
_REQUIRED = 1e6


def target_territories(hop_distances: np.ndarray, target_indices: np.ndarray, n_agents: int) -> np.ndarray:
    """The territory of every target.

    :param hop_distances: ``(N, N)`` hop distances of a connected graph.
    :param target_indices: ``(T,)`` the target nodes.
    :param n_agents: ``K``, the number of territories (>= 1).
    :return: ``(T,)`` int, the agent that owns each target of ``target_indices`` (in ``0..K-1``).
    """
    targets = np.asarray(target_indices, dtype=np.int64)
    return split_targets(np.asarray(hop_distances)[np.ix_(targets, targets)], targets, n_agents)


def site_territories(graph: GraphSpec, n_agents: int) -> np.ndarray:
    """:func:`target_territories` of ``graph``'s targets, from the distances between its targets
    alone (``graph.routes``: no all-pairs table on a large site). ``(T,)`` int."""
    return split_targets(graph.routes.between_targets(), graph.target_indices, n_agents)


def split_targets(between: np.ndarray, target_indices: np.ndarray, n_agents: int) -> np.ndarray:
    """:func:`target_territories` from ``between`` ``(T, T)``, the hop distances between the
    targets ``target_indices`` ``(T,)`` (in that order). ``(T,)`` int."""
    if n_agents < 1:
        raise GraphError(f"territories need at least one agent, got {n_agents}")
    targets = np.asarray(target_indices, dtype=np.int64)
    n_targets = targets.size
    if n_targets == 0:
        return np.zeros(0, dtype=np.int64)
    k = min(n_agents, n_targets)
    distances = np.asarray(between, dtype=np.float64)  # (T, T)
    medoids = _farthest_points(distances, k)
    capacity, required = math.ceil(n_targets / k), n_targets // k
    owner = np.full(n_targets, -1, dtype=np.int64)
    for _ in range(_MAX_ROUNDS):
        new_owner = _assign(distances, medoids, capacity, required)
        new_medoids = [_medoid(distances, np.flatnonzero(new_owner == c)) for c in range(k)]
        if np.array_equal(new_owner, owner) and new_medoids == medoids:
            break
        owner, medoids = new_owner, new_medoids
    # Agent i owns the territory with the i-th lowest target node: an order every agent derives
    # from the site alone.
    first_member = [int(targets[owner == c].min()) for c in range(k)]
    rank = np.empty(k, dtype=np.int64)
    rank[np.argsort(first_member, kind="stable")] = np.arange(k)
    return rank[owner]


def territory_nodes(
    hop_distances: np.ndarray, target_indices: np.ndarray, n_agents: int, n_nodes: int
) -> np.ndarray:
    """``(K, N)`` bool: ``[i, v]`` is True when node ``v`` is a target of agent ``i``'s territory."""
    owner = target_territories(hop_distances, target_indices, n_agents)
    owns = np.zeros((n_agents, n_nodes), dtype=bool)
    owns[owner, np.asarray(target_indices, dtype=np.int64)] = True
    return owns


def agent_territories(graph: GraphSpec, n_agents: int) -> list[tuple[int, ...]]:
    """Each agent's territory on ``graph`` as its target nodes in increasing order: agent ``i``'s
    at index ``i`` (what the neglect bound's scope ``territory`` takes as a policy setting)."""
    owns = site_territory_nodes(graph, n_agents)
    return [tuple(int(node) for node in np.flatnonzero(row)) for row in owns]


def site_territory_nodes(graph: GraphSpec, n_agents: int) -> np.ndarray:
    """:func:`territory_nodes` of ``graph`` by :func:`site_territories`: ``(K, N)`` bool."""
    owns = np.zeros((n_agents, graph.n_nodes), dtype=bool)
    owns[site_territories(graph, n_agents), graph.target_indices] = True
    return owns


def _farthest_points(distances: np.ndarray, k: int) -> list[int]:
    """``k`` indices into the ``(T, T)`` ``distances``, spread by farthest-point selection."""
    chosen = [int(np.argmax(distances.sum(axis=1)))]  # argmax takes the lowest index on ties
    nearest = distances[chosen[0]].copy()
    while len(chosen) < k:
        nearest[chosen] = -1.0  # never pick a medoid twice (relevant when targets coincide in distance)
        pick = int(np.argmax(nearest))
        chosen.append(pick)
        nearest = np.minimum(nearest, distances[pick])
    return chosen


def _assign(distances: np.ndarray, medoids: list[int], capacity: int, required: int) -> np.ndarray:
    """``(T,)`` territory of each target: the least total distance to medoids, at least
    ``required`` and at most ``capacity`` targets per territory."""
    slot_medoid = np.repeat(np.arange(len(medoids)), capacity)  # (K * capacity,) territory of a slot
    cost = distances[:, np.asarray(medoids)][:, slot_medoid]  # (T, K * capacity)
    cost[:, (np.arange(slot_medoid.size) % capacity) < required] -= _REQUIRED
    # Each medoid stays in its own territory, so no territory is ever left empty.
    for territory, medoid in enumerate(medoids):
        cost[medoid, slot_medoid != territory] = _FORBIDDEN
    rows, slots = linear_sum_assignment(cost)
    owner = np.empty(distances.shape[0], dtype=np.int64)
    owner[rows] = slot_medoid[slots]
    return owner


def _medoid(distances: np.ndarray, members: np.ndarray) -> int:
    """The member with the smallest summed distance to the other members (lowest index on ties)."""
    within = distances[np.ix_(members, members)].sum(axis=1)
    return int(members[int(np.argmin(within))])
