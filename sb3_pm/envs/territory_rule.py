"""The territory rule: each agent patrols its own territory's targets, most stale first.

One decision, written once, used two ways:

* the ``territory_patrol`` baseline (:mod:`sb3_pm.baselines.territory_patrol`) acts by it;
* the env's ``advice_input`` option flags, in each agent's map observation, the node the rule
  would move to next (:class:`TerritoryAdvice`), so a learned policy can take the rule's move as
  an input and learn when to follow it.

The rule reads only what the agent itself knows: its position, its own map's ``u`` and ``age`` of
each node, the site's road network and its own territory (a convention every agent derives alike
from the site plan, :mod:`sb3_pm.graphs.territories`). Nothing is communicated.

Per agent and step:

1. on one of its targets whose observed ``u`` is positive: dwell;
2. else keep heading for the goal chosen earlier until it is reached; otherwise choose, among its
   territory's other targets, the one with the highest own-map estimate ``min(u + age, u_max)``
   (``u`` grows by at most one per unobserved step; ties: nearest, then lowest index) and take one
   step along a shortest path of the road network;
3. a territory of one target is held once reached.

An agent whose convention walks its territory as a tour (``planned_tours``,
:mod:`sb3_pm.planning.conventions`) chooses its goal in step 2 otherwise: from one of its targets,
the tour's next target; from elsewhere, its nearest target (ties: lowest index). This is the plan's
``tour`` rule (:func:`sb3_pm.planning.group_patrol.tour_move`) on the agent's own map.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from sb3_pm.graphs.routes import DenseRoutes, Routes


def nearest_first(
    candidates: np.ndarray, distances: np.ndarray, keys: np.ndarray | None = None
) -> np.ndarray:
    """``candidates`` sorted by descending ``keys`` (if given), then ascending distance, then index.

    ``np.lexsort`` sorts by its *last* key first, so the keys are passed in reverse priority.
    Ties are broken deterministically, which keeps every rule reproducible without an rng.
    """
    order_keys: list[np.ndarray] = [candidates, distances[candidates]]
    if keys is not None:
        order_keys.append(-keys[candidates])
    return candidates[np.lexsort(order_keys)]


def territory_move(
    position: int,
    own: np.ndarray,
    u: np.ndarray,
    age: np.ndarray,
    goal: int | None,
    u_max: float,
    routes: Routes,
    tour_next: Mapping[int, int] | None = None,
) -> tuple[int, int | None]:
    """One agent's move by the territory rule, and the goal it keeps for its next step.

    :param position: the agent's node.
    :param own: ``(T_i,)`` int, the targets of its territory (at least one).
    :param u: ``(N,)`` its own map's last observed uncertainty of each node.
    :param age: ``(N,)`` its own map's steps since each node was last observed.
    :param goal: the goal it kept from the previous step (``None``: none).
    :param u_max: the uncertainty cap.
    :param routes: the road network's distances to targets and next hops towards them
        (:mod:`sb3_pm.graphs.routes`; ``graph.routes``).
    :param tour_next: for an agent that walks its territory as a tour, each of its targets' next
        target on the tour (``None``: stalest first).
    :return: ``(destination node, goal to keep or None)``.
    """
    if position in own and u[position] > 0:
        return position, None
    if (goal is None or goal == position) and tour_next is not None:
        if position in tour_next:
            goal = tour_next[position]
            if goal == position:
                return position, None  # a tour of one target: hold it
        else:  # own is sorted, so the lexsort breaks distance ties by the lowest node
            goal = int(own[np.lexsort((own, routes.distances(position, own)))[0]])
    elif goal is None or goal == position:
        others = own[own != position]
        if others.size == 0:
            return position, goal  # a territory of one target: hold it
        estimate = np.minimum(u + age, u_max)
        # nearest_first's order (stalest, then nearest, then lowest index) on the targets'
        # distances alone: the routes of a large site hold no (N, N) row to index
        order = np.lexsort((others, routes.distances(position, others), -estimate[others]))
        goal = int(others[order[0]])
    return routes.next_hop(position, goal), goal


class TerritoryAdvice:
    """The territory rule's next move for every agent of a team, step by step (``advice_input``).

    Each agent's rule keeps its own goal between steps, as the baseline does; the goal follows the
    rule's own moves, whatever the agent actually did (a goal is dropped once the agent stands on
    it, or while it dwells on one of its targets).

    :param territory: ``(n_agents, N)`` bool, each agent's territory.
    :param distances: the site's :class:`~sb3_pm.graphs.routes.Routes` (``graph.routes``), or its
        ``(N, N)`` hop distances with ``next_hop`` ``(N, N)``, the first hop of a shortest path.
    :param u_max: the uncertainty cap.
    :param tours: per agent, its targets in tour order where it walks a tour, else ``None``
        (default: every agent stalest first).
    """

    def __init__(
        self,
        territory: np.ndarray,
        distances: Routes | np.ndarray,
        next_hop: np.ndarray | None,
        u_max: float,
        tours: Sequence[Sequence[int] | None] | None = None,
    ) -> None:
        #: Each agent's own targets, ``(T_i,)`` int node indices (empty: no territory, no advice).
        self.own = [np.flatnonzero(row) for row in territory]
        tours = [None] * len(self.own) if tours is None else list(tours)
        if len(tours) != len(self.own) or any(
            tour is not None and sorted(tour) != own.tolist() for tour, own in zip(tours, self.own)
        ):
            raise ValueError("TerritoryAdvice's tours must order each touring agent's own targets")
        #: Per agent, each target's next target on its tour (``None``: it walks stalest first).
        self.tour_next: list[dict[int, int] | None] = [
            None if tour is None else {int(a): int(b) for a, b in zip(tour, list(tour[1:]) + list(tour[:1]))}
            for tour in tours
        ]
        if isinstance(distances, np.ndarray):
            if next_hop is None:
                raise ValueError("TerritoryAdvice takes (N, N) distances with an (N, N) next_hop")
            targets = np.flatnonzero(np.asarray(territory).any(axis=0))
            distances = DenseRoutes(distances, next_hop, targets)
        #: distances to the targets and next hops towards them
        self.routes: Routes = distances
        self.u_max = float(u_max)
        self.goals: list[int | None] = [None] * len(self.own)

    def reset(self) -> None:
        """A new episode: no goal kept."""
        self.goals = [None] * len(self.own)

    def state_dict(self) -> dict[str, list[int | None]]:
        """The goals kept between steps (a checkpoint's)."""
        return {"goals": list(self.goals)}

    def load_state_dict(self, state: dict[str, list[int | None]]) -> None:
        """Put back a :meth:`state_dict` of advice for the same territories."""
        self.goals = [None if goal is None else int(goal) for goal in state["goals"]]

    def move(self, i: int, position: int, u: np.ndarray, age: np.ndarray) -> int:
        """Agent ``i``'s move by the rule (it must own a target), keeping its goal for the next
        step. ``u``, ``age``: ``(N,)`` its own map."""
        move, self.goals[i] = territory_move(
            position, self.own[i], u, age, self.goals[i], self.u_max, self.routes, self.tour_next[i]
        )
        return move

    def moves(self, positions: np.ndarray, u: np.ndarray, age: np.ndarray, active: np.ndarray) -> np.ndarray:
        """``(n_agents,)`` int: each agent's move by the rule, ``-1`` for an agent with no territory
        or a failed one. ``u``, ``age``: ``(n_agents, N)`` each agent's own map."""
        moves = np.full(len(self.own), -1, dtype=np.int64)
        for i, own in enumerate(self.own):
            if own.size and active[i]:
                moves[i] = self.move(i, int(positions[i]), u[i], age[i])
        return moves
