"""Pricing a plan: each agent alone on its group, simulated and cached (docs/PLANNING.md "Plans").

Priced as if each agent were alone on its group (an agent crossing another's target only lowers
it), a plan's cost is a sum of solo costs, one per agent, plus what each dropped target costs left
alone. :class:`GroupPricer` caches the solo costs per (start, group) for one episode and walks
large batches of them at once (:func:`~sb3_pm.planning.batch_pricing.solo_costs`). Everything is
in the labels of :class:`~sb3_pm.planning.target_tables.TargetTables`.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
from scipy.optimize import linear_sum_assignment

from sb3_pm.graphs.tours import approximate_tour
from sb3_pm.planning.batch_pricing import solo_costs
from sb3_pm.planning.group_patrol import dropped_cost, solo_cost
from sb3_pm.planning.target_tables import TargetTables

__all__ = ["BATCH_MAX_WALKS", "BATCH_MIN_WALKS", "GroupPricer"]

#: The fewest unpriced walks that :meth:`GroupPricer.prefetch` prices as one NumPy batch (below it
#: the walks go one by one in Python, whose cost grows with the walk's length and the group's
#: size, where a batch's is mostly a fixed cost per step: research/LOG.md §3u).
BATCH_MIN_WALKS = 64
#: The most walks priced in one NumPy batch, so that a large site's batch stays within memory.
BATCH_MAX_WALKS = 20_000
#: Tables of up to this many entries are held as Python lists for the one-by-one walks; larger ones
#: turn a row into a list when a walk first reads it (a walk reads few rows; a list of every row
#: of a 20,000-node site with 2,000 targets takes about a gigabyte).
EAGER_ROWS_MAX_ENTRIES = 2_000_000


class _RowsOnDemand:
    """``table[node][column]`` for the one-by-one walks, each row made a Python list on first use."""

    def __init__(self, table: np.ndarray) -> None:
        self.table = table
        self.rows: dict[int, list[int]] = {}

    def __getitem__(self, node: int) -> list[int]:
        row = self.rows.get(node)
        if row is None:
            row = self.rows[node] = self.table[node].tolist()
        return row


def _rows(table: np.ndarray) -> list[list[int]] | _RowsOnDemand:
    """``table`` ``(N, T)`` as rows of Python ints, all at once where it is small."""
    return table.tolist() if table.size <= EAGER_ROWS_MAX_ENTRIES else _RowsOnDemand(table)


class GroupPricer:
    """Solo costs, cached, for one episode's starts and initial uncertainties."""

    def __init__(
        self,
        tables: TargetTables,
        starts: np.ndarray,
        initial: np.ndarray,
        max_cycles: int,
        u_max: int,
        tour_groups: bool = True,
    ) -> None:
        """:param starts: ``(n,)`` the agents' start *labels*; :param initial: ``(N,)`` ``u`` at reset
        by node. Groups, starts and targets are all in ``tables``' labels."""
        self.tour_groups = tour_groups
        self.starts = [int(s) for s in starts]
        n_targets = tables.between.shape[0]
        self.initial = {label: int(initial[tables.node[label]]) for label in range(n_targets)}
        self.max_cycles, self.u_max = max_cycles, u_max
        self.distances = _rows(tables.distances)
        self.next_hop = _rows(tables.next_hop)
        self.between = tables.between
        self.distance_array = tables.distances
        self.next_hop_array = tables.next_hop
        self._cache: dict[tuple[int, tuple[int, ...]], int] = {}
        #: (start, group) -> the cheaper rule and the group in that rule's order
        self.rule: dict[tuple[int, tuple[int, ...]], tuple[str, tuple[int, ...]]] = {}
        self._tours: dict[tuple[int, ...], tuple[int, ...]] = {}

    def _tour(self, group: tuple[int, ...]) -> tuple[int, ...]:
        if group not in self._tours:
            order = approximate_tour(np.asarray(group, dtype=np.int64), self.between)
            self._tours[group] = tuple(int(t) for t in order)
        return self._tours[group]

    def _options(self, group: tuple[int, ...]) -> list[tuple[str, tuple[int, ...]]]:
        """The rules a group is priced by, each with the group in its order (``tour`` from 3 targets,
        where ``tour_groups``)."""
        tour = self.tour_groups and len(group) >= 3
        return [("stalest", group)] + ([("tour", self._tour(group))] if tour else [])

    def solo(self, start: int, group: tuple[int, ...]) -> int:
        """The agent's cost alone on ``group`` by the cheaper of :meth:`_options`' rules."""
        key = (start, group)
        if key not in self._cache:
            priced = []
            for rule, ordered in self._options(group):
                initial = [self.initial[t] for t in ordered]
                cost = solo_cost(
                    start, ordered, initial, self.max_cycles, self.u_max, self.distances, self.next_hop, rule
                )
                priced.append((cost, rule, ordered))
            cost, rule, ordered = min(priced, key=lambda item: item[0])
            self._cache[key], self.rule[key] = cost, (rule, ordered)
        return self._cache[key]

    def prefetch(self, groups: Iterable[tuple[int, ...]]) -> None:
        """Price every start on every group of ``groups`` not priced yet, in batches."""
        self.prefetch_pairs((start, group) for group in groups for start in self.starts)

    def prefetch_pairs(self, pairs: Iterable[tuple[int, tuple[int, ...]]]) -> None:
        """Price every (start, group) of ``pairs`` not priced yet, in batches of at most
        :data:`BATCH_MAX_WALKS` walks."""
        unpriced = list(dict.fromkeys(pair for pair in pairs if pair not in self._cache))
        walks = [
            (start, group, rule, ordered)
            for start, group in unpriced
            for rule, ordered in self._options(group)
        ]
        if len(walks) < BATCH_MIN_WALKS:  # a small batch walks faster one by one
            for start, group in unpriced:
                self.solo(start, group)
            return
        for first in range(0, len(walks), BATCH_MAX_WALKS):
            self._price_batch(walks[first : first + BATCH_MAX_WALKS])

    def _price_batch(self, walks: list[tuple[int, tuple[int, ...], str, tuple[int, ...]]]) -> None:
        costs = solo_costs(
            [start for start, _, _, _ in walks],
            [ordered for _, _, _, ordered in walks],
            [rule for _, _, rule, _ in walks],
            [[self.initial[t] for t in ordered] for _, _, _, ordered in walks],
            self.max_cycles,
            self.u_max,
            self.distance_array,
            self.next_hop_array,
        )
        # as solo(): the cheaper rule, stalest on a tie (it comes first)
        for (start, group, rule, ordered), cost in zip(walks, costs.tolist()):
            key = (start, group)
            if key not in self._cache or cost < self._cache[key]:
                self._cache[key], self.rule[key] = cost, (rule, ordered)

    def dropped(self, target: int) -> int:
        return dropped_cost(self.initial[target], self.max_cycles, self.u_max)

    def assign(self, groups: list[tuple[int, ...]]) -> tuple[int, list[int]]:
        """The least summed solo cost over agent-to-group matchings, and each agent's group index."""
        costs = np.array([[self.solo(s, g) for g in groups] for s in self.starts], dtype=np.float64)
        rows, cols = linear_sum_assignment(costs)
        order = [0] * len(self.starts)
        for row, col in zip(rows, cols):
            order[row] = int(col)
        return int(costs[rows, cols].sum()), order

    def total(self, groups: list[tuple[int, ...]], dropped: tuple[int, ...]) -> tuple[int, list[int]]:
        cost, order = self.assign(groups)
        return cost + sum(self.dropped(t) for t in dropped), order
