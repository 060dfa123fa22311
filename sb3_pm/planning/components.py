"""The components bound: a lower bound that keeps each agent whole (docs/PLANNING.md "By components").

Targets one hop apart form a **component** (a connected group of targets under target-to-target
edges). An agent can walk from target to target inside a component without stepping off targets,
but between two components it spends at least one step off targets, since their targets are at
least two hops apart. The relaxation keeps three things of the true dynamics:

* every agent is whole: at each step it stands in one component or off targets;
* leaving a component costs at least one step off targets before any other is entered, and an
  agent's first arrival at a component waits for the hops from its start;
* each component's summed uncertainty ``S_C`` follows eq. (1) with its occupied targets ``o_C <=
  min(m_C, t_C)`` (``m_C`` agents in it, ``t_C`` targets), those with ``u > 0`` at most ``min(o_C,
  S_C)``, and at most ``floor(S_C / u_max)`` empty targets at the cap. For a one-target component
  this is exact.

It forgets where inside a component the agents stand, except in the first :data:`EXACT_STEPS`
steps, which are played node by node (where agents sort out which target each takes). Given the
agent counts, the smallest next ``S_C`` is the greedy one and it grows with ``S_C``, so a dynamic
programme over (agents per component, agents free off targets, agents on their way with their
earliest step in each component, ``S_C`` per component) finds the relaxed minimum exactly.
A state is dropped where another of the same counts, with the same ``S_C`` in all components but
one, is no higher in that one and in cost so far, and so is any state whose cost so far plus the
step-by-step bound from its total already exceeds an achievable score (``ceiling``): neither can
lead to a lower minimum.

The programme grows with the number of ways to place the agents, so it is computed only where
that number and the surviving states stay small (``None`` otherwise).
"""

from __future__ import annotations

import itertools
from math import comb

import numpy as np

from sb3_pm.errors import InputError
from sb3_pm.graphs import GraphSpec
from sb3_pm.planning.bound import checked_starts, initial_targets
from sb3_pm.planning.joint_moves import after_step, distinct_cheapest, joint_choices

__all__ = [
    "EXACT_STEPS",
    "MAX_EXACT_MOVES",
    "MAX_PLACEMENTS",
    "MAX_STATES",
    "component_bound",
    "component_bound_applies",
    "target_components",
]

#: The most placements of the agents over the components (and off targets) the programme takes.
MAX_PLACEMENTS = 64
#: The most states the programme keeps after any step before it gives up.
MAX_STATES = 400_000
#: The first steps played exactly, node by node, before the relaxation takes over.
EXACT_STEPS = 2
#: The most joint first moves the exact start enumerates; with more, the relaxation starts at once.
MAX_EXACT_MOVES = 200_000
#: Rows of the exact start's last step expanded at once (bounds its memory).
_EXACT_CHUNK = 1_000_000
#: The hops to a component no walk reaches.
_NEVER = 1 << 30

# A configuration: (agents per component, agents free off targets, agents on their way). An agent on
# its way is its earliest step in each component; once every component is open to it, it is free.
Config = tuple[tuple[int, ...], int, tuple[tuple[int, ...], ...]]


def target_components(between: np.ndarray) -> list[np.ndarray]:
    """The targets' components under target-to-target edges.

    :param between: ``(T, T)`` hop distances between the targets.
    :return: one int array of target positions (indices into the targets) per component, in order
        of their smallest member.
    """
    adjacent = np.asarray(between) == 1
    label = np.full(adjacent.shape[0], -1, dtype=np.int64)
    groups: list[np.ndarray] = []
    for seed in range(adjacent.shape[0]):
        if label[seed] >= 0:
            continue
        label[seed] = len(groups)
        members, frontier = [seed], [seed]
        while frontier:
            for other in np.flatnonzero(adjacent[frontier.pop()] & (label < 0)).tolist():
                label[other] = len(groups)
                members.append(other)
                frontier.append(other)
        groups.append(np.array(sorted(members), dtype=np.int64))
    return groups


def _costs_to_go(n_targets: int, n_agents: int, max_cycles: int, u_max: int) -> np.ndarray:
    """``(T u_max + 1, K + 1)``: entry ``[s, r]`` is no more than any team's summed ``S`` over the
    next ``r`` steps from a total ``s`` (the step-by-step recursion with every agent on a target)."""
    occupied = min(n_agents, n_targets)
    totals = np.arange(n_targets * u_max + 1, dtype=np.int64)

    def step(total: np.ndarray) -> np.ndarray:
        capped = np.minimum(total // u_max, n_targets)
        return total + n_targets - occupied - np.minimum(occupied, total) - capped

    # Below ``occupied`` the map may fall as S grows; from there on it never does, so its least
    # value over S' >= S is at S, occupied - 1 or occupied.
    floor_value = min(step(np.array([max(occupied - 1, 0)]))[0], step(np.array([occupied]))[0])
    to_go = np.zeros((totals.size, max_cycles + 1), dtype=np.int64)
    current = totals
    for remaining in range(1, max_cycles + 1):
        nxt = step(current)
        nxt = np.where(current < occupied, np.minimum(nxt, floor_value), nxt)
        current = np.maximum(nxt, 0)
        to_go[:, remaining] = to_go[:, remaining - 1] + current
    return to_go


def _undominated(sums: np.ndarray, cost: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Drop states another state beats (no higher cost, no higher sum) along each component in turn.

    :param sums: ``(states, C)``; :param cost: ``(states,)``; both already free of exact repeats.
    """
    n_components = sums.shape[1]
    big = np.int64(1) << 40
    for last in range(n_components):
        others = [c for c in range(n_components) if c != last]
        order = np.lexsort((cost, sums[:, last], *[sums[:, c] for c in others[::-1]]))
        sums, cost = sums[order], cost[order]
        new_group = np.ones(cost.size, dtype=bool)
        if others:
            new_group[1:] = (sums[1:][:, others] != sums[:-1][:, others]).any(axis=1)
        else:
            new_group[1:] = False
        group = np.cumsum(new_group) - 1
        # the least cost before each state within its group: later groups are shifted far below
        before = np.where(new_group, big - 1, np.concatenate([[big - 1], cost[:-1]]))
        least_before = np.minimum.accumulate(before - group * big) + group * big
        keep = cost < least_before
        sums, cost = sums[keep], cost[keep]
    return sums, cost


def _starting_states(
    graph: GraphSpec, starts: np.ndarray, initial: np.ndarray, groups: list[np.ndarray]
) -> dict[Config, tuple[np.ndarray, np.ndarray]]:
    """The state at reset: each agent in the component it stands in, or on its way to all of them."""
    arrival = _hops_to_components(graph, starts, groups)  # (n, C)
    placed = [0] * len(groups)
    on_the_way: list[tuple[int, ...]] = []
    for agent in range(starts.size):
        inside = np.flatnonzero(arrival[agent] == 0)
        if inside.size:
            placed[int(inside[0])] += 1
        else:
            on_the_way.append(tuple(int(h) for h in arrival[agent]))
    sums = np.array([[int(initial[g].sum()) for g in groups]], dtype=np.int64)
    return {(tuple(placed), 0, tuple(sorted(on_the_way))): (sums, np.zeros(1, dtype=np.int64))}


def _hops_to_components(graph: GraphSpec, nodes: np.ndarray, groups: list[np.ndarray]) -> np.ndarray:
    """``(len(nodes), C)`` the hops from each node to each component's nearest target (a large
    number where none is reachable)."""
    to_targets = graph.routes.to_targets(nodes)  # (M, T)
    reachable = (to_targets >= 0) & (to_targets < graph.n_nodes)
    hops = np.where(reachable, to_targets, _NEVER)
    return np.stack([hops[:, g].min(axis=1) for g in groups], axis=1)


def _exact_start(
    graph: GraphSpec,
    starts: np.ndarray,
    initial: np.ndarray,
    u_max: int,
    steps: int,
    groups: list[np.ndarray],
) -> dict[Config, tuple[np.ndarray, np.ndarray]]:
    """The relaxation's states after the first ``steps`` steps, played exactly from the starts.

    The steps before the last enumerate every joint move, node by node. On the last only where each
    agent ends matters to the relaxation: on which target, or off targets and how many hops from each
    component, so each agent's options there are the targets it can reach and one "off" with the
    fewest hops of the nodes off targets it can reach. Each state keeps its least cost, so the
    start-up waste the relaxation would not see (agents that must first sort out which target each
    takes) is counted exactly.
    """
    n_targets = initial.size
    target_of = np.full(graph.n_nodes, -1, dtype=np.int64)
    target_of[graph.target_indices] = np.arange(n_targets)
    component_of = np.empty(n_targets, dtype=np.int64)
    for index, group in enumerate(groups):
        component_of[group] = index
    reach = [np.flatnonzero(row).astype(np.int64) for row in graph.reachable]
    at, values, cost = starts[None, :], initial[None, :], np.zeros(1, dtype=np.int64)
    for _ in range(steps - 1):  # every joint move; rows with the same nodes and u merged
        nodes, parent = joint_choices(reach, at)
        values = after_step(target_of[nodes], values[parent], u_max)
        cost = cost[parent] + values.sum(axis=1)
        at = np.sort(nodes, axis=1)  # the agents are alike: only where they stand matters
        kept = distinct_cheapest(np.concatenate([at, values], axis=1), cost)
        at, values, cost = at[kept], values[kept], cost[kept]
    # The last step: each agent onto a target it can reach (its index) or off targets. Off targets
    # only the hops onward matter; one option takes, per component, the fewest hops of any node off
    # targets it can reach (an agent there is no further from any component): -1 - its index.
    onward = _hops_to_components(graph, np.arange(graph.n_nodes), groups)  # (N, C)
    nearest: dict[tuple[int, ...], int] = {}
    landing = []
    for nodes in reach:
        on = target_of[nodes]
        options = np.unique(on[on >= 0]).tolist()
        if (on < 0).any():
            hops = tuple(int(h) for h in onward[nodes[on < 0]].min(axis=0))
            options.append(-1 - nearest.setdefault(hops, len(nearest)))
        landing.append(np.array(options, dtype=np.int64))
    signatures = sorted(nearest, key=nearest.__getitem__)
    widest = max(options.size for options in landing) ** starts.size
    per_part = max(1, _EXACT_CHUNK // widest)
    gathered: dict[Config, list[tuple[np.ndarray, np.ndarray]]] = {}
    for low in range(0, at.shape[0], per_part):
        part = slice(low, low + per_part)
        chosen, parent = joint_choices(landing, at[part])
        after = after_step(chosen, values[part][parent], u_max)
        total = cost[part][parent] + after.sum(axis=1)
        sums = np.stack([after[:, g].sum(axis=1) for g in groups], axis=1)
        placed = np.zeros((chosen.shape[0], len(groups)), dtype=np.int64)
        for agent in range(chosen.shape[1]):
            rows = np.flatnonzero(chosen[:, agent] >= 0)
            np.add.at(placed, (rows, component_of[chosen[rows, agent]]), 1)
        away = np.sort(np.where(chosen < 0, -1 - chosen, -1), axis=1)  # signatures, -1 first
        keys, inverse = np.unique(np.concatenate([placed, away], axis=1), axis=0, return_inverse=True)
        inverse = inverse.ravel()
        for index, key in enumerate(keys):
            rows = np.flatnonzero(inverse == index)
            counts, off = key[: len(groups)], key[len(groups) :]
            # an agent off targets after this step reaches a component no sooner than its hops on
            on_the_way = tuple(
                sorted(tuple(int(steps + h) for h in signatures[sig]) for sig in off if sig >= 0)
            )
            config = (tuple(int(c) for c in counts), 0, on_the_way)
            gathered.setdefault(config, []).append((sums[rows], total[rows]))
    return {key: _cheapest(parts) for key, parts in gathered.items()}


def _cheapest(parts: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """The states of ``parts`` joined, each distinct sums once at its least cost."""
    sums = np.concatenate([p[0] for p in parts])
    cost = np.concatenate([p[1] for p in parts])
    kept = distinct_cheapest(sums, cost)
    return sums[kept], cost[kept]


def component_bound_applies(graph: GraphSpec, n_agents: int, u_max: int) -> bool:
    """Whether :func:`component_bound` computes a figure here, rather than ``None`` at once: at most
    :data:`MAX_PLACEMENTS` placements of the agents, and every component below ``u_max`` targets.
    (It may still give up on :data:`MAX_STATES`.)"""
    sizes = [g.size for g in target_components(graph.routes.between_targets())]
    return bool(sizes) and comb(n_agents + len(sizes), len(sizes)) <= MAX_PLACEMENTS and max(sizes) < u_max


def component_bound(
    graph: GraphSpec,
    starts: np.ndarray,
    max_cycles: int,
    u_max: int,
    initial_uncertainty: np.ndarray | None = None,
    ceiling: float | None = None,
) -> float | None:
    """The components bound on ``avg_uncertainty`` (arguments as
    :func:`~sb3_pm.planning.bound.stepwise_bound`).

    :param ceiling: an ``avg_uncertainty`` some team achieves on this episode (for example the
        planner's replayed score); only used to drop states, so the result does not depend on it
        unless it is below the relaxed minimum, and then the result is ``floor(ceiling * K) / K``,
        still a valid bound.
    :return: the bound, or ``None`` where the programme is too large (more than
        :data:`MAX_PLACEMENTS` placements, more than :data:`MAX_STATES` states after a step, or a
        component with as many targets as ``u_max``).
    """
    starts = checked_starts(graph, starts, max_cycles, u_max)
    initial = initial_targets(graph, initial_uncertainty, u_max)
    if initial.size == 0:
        return 0.0
    if ceiling is None:
        raise InputError("component_bound needs a ceiling: an avg_uncertainty some team achieves")
    if not component_bound_applies(graph, int(starts.size), u_max):
        return None
    groups = target_components(graph.routes.between_targets())
    sizes = np.array([g.size for g in groups], dtype=np.int64)  # (C,)
    n_agents, n_components = int(starts.size), len(groups)
    to_go = _costs_to_go(int(initial.size), n_agents, max_cycles, u_max)
    limit = int(np.floor(ceiling * max_cycles + 1e-6))
    first_moves = float(np.prod([float(graph.reachable[s].sum()) for s in starts]))
    exact = min(EXACT_STEPS, max_cycles) if first_moves <= MAX_EXACT_MOVES else 0
    if exact:
        states = {}
        for config, (sums, cost) in _exact_start(graph, starts, initial, u_max, exact, groups).items():
            alive = cost + to_go[sums.sum(axis=1), max_cycles - exact] <= limit
            if alive.any():
                states[config] = _undominated(sums[alive], cost[alive])
        if not states:
            return limit / max_cycles
    else:
        states = _starting_states(graph, starts, initial, groups)
    successors: dict[tuple, list[Config]] = {}

    def moves(config: Config, k: int) -> list[Config]:
        """The placements one step can lead to from ``config``, at step ``k``."""
        counts, free, on_the_way = config
        free += sum(1 for arrival in on_the_way if max(arrival) <= k)
        on_the_way = tuple(arrival for arrival in on_the_way if max(arrival) > k)
        opened = [[None, *[c for c in range(n_components) if arrival[c] <= k]] for arrival in on_the_way]
        key = (counts, free, on_the_way, tuple(map(tuple, opened)))
        if key not in successors:
            found: set[Config] = set()
            for stay in itertools.product(*[range(c + 1) for c in counts]):
                left = sum(counts) - sum(stay)
                for enter in itertools.product(range(free + 1), repeat=n_components):
                    if sum(enter) > free:
                        continue
                    for chosen in itertools.product(*opened):
                        after = [s + e for s, e in zip(stay, enter)]
                        still = []
                        for arrival, into in zip(on_the_way, chosen):
                            if into is None:
                                still.append(arrival)
                            else:
                                after[into] += 1
                        found.add((tuple(after), left + free - sum(enter), tuple(sorted(still))))
            successors[key] = sorted(found)
        return successors[key]

    for k in range(exact + 1, max_cycles + 1):
        incoming: dict[Config, list[tuple[np.ndarray, np.ndarray]]] = {}
        for config, held in states.items():
            for after in moves(config, k):
                incoming.setdefault(after, []).append(held)
        states = {}
        for config, parts in incoming.items():
            # the same sums reached from several placements: keep the cheapest
            sums, cost = _cheapest(parts) if len(parts) > 1 else parts[0]
            occupied = np.minimum(np.array(config[0]), sizes)[None, :]
            capped = np.minimum(sizes[None, :] - occupied, sums // u_max)
            sums = sums + sizes[None, :] - occupied - np.minimum(occupied, sums) - capped
            cost = cost + sums.sum(axis=1)
            alive = cost + to_go[sums.sum(axis=1), max_cycles - k] <= limit
            if alive.any():
                states[config] = _undominated(sums[alive], cost[alive])
        if not states:
            return limit / max_cycles  # nothing stays at or below the ceiling
        if sum(held[1].size for held in states.values()) > MAX_STATES:
            return None
    return min(int(held[1].min()) for held in states.values()) / max_cycles
