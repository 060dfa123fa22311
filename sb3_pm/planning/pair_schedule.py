"""One agent on a group of two targets, scheduled exactly (docs/PLANNING.md "Plans").

Two targets ``a`` and ``b`` and the shortest path ``P = (p_0 = a, ..., p_L = b)`` between them. Once
the agent is on ``P`` it moves along it; the least summed ``u_a + u_b`` over the remaining steps is
a dynamic programme over ``(remaining steps r, path index j, u_a, u_b)``:

    V_r[j] = min over j' in {j - 1, j, j + 1} of C_r[j'],
    C_r[j'](u_a, u_b) = u_a' + u_b' + V_{r-1}[j'](u_a', u_b'),

where ``u'`` is eq. (1) with the agent on ``p_{j'}``. ``C_r[j']`` does not depend on where the
agent came from, so a step costs ``L + 1`` gathers over the ``(u_max + 1)²`` grid. The agent
enters ``P`` at the node that is cheapest counting its walk there from its start, during which
both targets grow.

Adjacent targets (``L = 1``) are held at ``u`` 0 and 1 whatever the dwell; the programme matters
for targets further apart, where every crossing adds to the pair's sum for good and the best
switching times are not the greedy ones (dwell until 0, then cross).
"""

from __future__ import annotations

import numpy as np

from sb3_pm.errors import InputError

__all__ = ["PairSchedule", "shortest_path"]

#: Paths longer than this many hops are left to the greedy group rule: the table grows with L.
MAX_PATH_HOPS = 6


def shortest_path(next_hop: np.ndarray, source: int, target: int) -> list[int]:
    """The nodes of the shortest path from ``source`` to ``target`` that ``next_hop`` follows."""
    path = [int(source)]
    while path[-1] != target:
        path.append(int(next_hop[path[-1], target]))
    return path


class PairSchedule:
    """The exact schedule of one agent on targets ``a`` and ``b``.

    :param hop_distances: ``(N, N)`` hop distances.
    :param next_hop: ``(N, N)`` first node of a shortest path.
    :param a: one target; :param b: the other.
    :param max_cycles: ``K``; :param u_max: the cap.
    :param keep_actions: keep the ``(K, L + 1, U + 1, U + 1)`` int8 move table that :meth:`move`
        reads (pricing alone needs only the first values).
    """

    def __init__(
        self,
        hop_distances: np.ndarray,
        next_hop: np.ndarray,
        a: int,
        b: int,
        max_cycles: int,
        u_max: int,
        keep_actions: bool = False,
    ) -> None:
        if a == b:
            raise InputError(f"a pair schedule needs two different targets, got {a} twice")
        self.path = shortest_path(next_hop, a, b)
        if len(self.path) - 1 > MAX_PATH_HOPS:
            raise InputError(
                f"targets {a} and {b} are {len(self.path) - 1} hops apart, above {MAX_PATH_HOPS}"
            )
        self.distances = hop_distances
        self.next_hop = next_hop
        self.max_cycles, self.u_max = max_cycles, u_max
        self._index = {node: j for j, node in enumerate(self.path)}
        # Values are needed at r >= K - D only: an entry walk takes at most D (the diameter) steps.
        self._oldest = max(0, max_cycles - int(hop_distances.max()) - 1)
        self._solve(keep_actions)

    def _step_costs(self, previous: np.ndarray) -> np.ndarray:
        """``C[j']`` for every path index from ``V_{r-1}`` (``previous``: ``(L + 1, U + 1, U + 1)``)."""
        levels = np.arange(self.u_max + 1)
        grow, clear = np.minimum(levels + 1, self.u_max), np.maximum(levels - 1, 0)
        last = len(self.path) - 1
        costs = np.empty_like(previous)
        for j in range(last + 1):
            ua = clear if j == 0 else grow
            ub = clear if j == last else grow
            costs[j] = ua[:, None] + ub[None, :] + previous[j][np.ix_(ua, ub)]
        return costs

    def _solve(self, keep_actions: bool) -> None:
        size, last = self.u_max + 1, len(self.path) - 1
        value = np.zeros((last + 1, size, size), dtype=np.float64)
        #: values[r - oldest] = V_r, for r = oldest .. K
        self._values = [value] if self._oldest == 0 else []
        self._actions = (
            np.zeros((self.max_cycles, last + 1, size, size), dtype=np.int8) if keep_actions else None
        )
        for r in range(1, self.max_cycles + 1):
            costs = self._step_costs(value)  # (L + 1, U + 1, U + 1)
            # choices[j, m]: destination index of move m in (-1, 0, +1) from j, clipped to the path
            value = np.empty_like(costs)
            for j in range(last + 1):
                options = [d for d in (j - 1, j, j + 1) if 0 <= d <= last]
                stacked = costs[options]  # (moves, U + 1, U + 1)
                pick = stacked.argmin(axis=0)
                value[j] = np.take_along_axis(stacked, pick[None], axis=0)[0]
                if self._actions is not None:
                    self._actions[r - 1, j] = np.asarray(options, dtype=np.int8)[pick]
            if r >= self._oldest:
                self._values.append(value)

    def _value(self, remaining: int) -> np.ndarray:
        return self._values[remaining - self._oldest]

    def entry(self, start: int, initial_a: int, initial_b: int) -> tuple[int, int]:
        """The least ``Σ_k (u_a + u_b)`` over the episode from ``start``, and the path node to enter by.

        :param initial_a: ``u_a`` at reset; :param initial_b: ``u_b`` at reset.
        """
        cap, horizon = self.u_max, self.max_cycles
        best_cost, best_node = None, self.path[0]
        for j, node in enumerate(self.path):
            walk = int(self.distances[start, node])
            if walk >= horizon:
                continue
            if walk == 0:
                cost = float(self._value(horizon)[j, initial_a, initial_b])
            else:
                steps = np.arange(1, walk)  # the walk's steps before arriving, both targets empty
                ua, ub = np.minimum(initial_a + steps, cap), np.minimum(initial_b + steps, cap)
                before_a, before_b = min(initial_a + walk - 1, cap), min(initial_b + walk - 1, cap)
                arrival = self._step_costs(self._value(horizon - walk))[j, before_a, before_b]
                cost = float(ua.sum() + ub.sum() + arrival)
            if best_cost is None or cost < best_cost:
                best_cost, best_node = cost, node
        if best_cost is None:  # the pair is out of reach within the episode: both grow throughout
            steps = np.arange(1, horizon + 1)
            best_cost = float(
                np.minimum(initial_a + steps, cap).sum() + np.minimum(initial_b + steps, cap).sum()
            )
        return int(round(best_cost)), best_node

    def move(self, position: int, entry_node: int, u_a: int, u_b: int, remaining: int) -> int:
        """The agent's next node: the scheduled move on the path, else a step towards ``entry_node``."""
        if self._actions is None:
            raise InputError("this pair schedule was built for pricing only (keep_actions=False)")
        j = self._index.get(position)
        if j is None:
            return int(self.next_hop[position, entry_node])
        return self.path[int(self._actions[remaining - 1, j, u_a, u_b])]
