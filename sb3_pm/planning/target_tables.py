"""Hop distances and next hops towards the targets only, in the planner's labels (docs/PLANNING.md "Plans").

A plan's walks only ever head for targets, so the planner needs two ``(N, T)`` tables, not the
``(N, N)`` all-pairs ones: on a site of 5,000 nodes and 500 targets that is 2.5 million entries
instead of 25 million per table.

The tables are indexed by *labels*: the targets are relabelled ``0 .. T-1`` in increasing node
order, the other nodes ``T .. N-1`` in increasing order. A target's label is then also its column,
so code written for ``distances[a][b]`` on ``(N, N)`` tables runs unchanged on ``(N, T)`` ones, and
every tie-break by node index (the stalest rule's lowest target, a path's smallest-index
neighbour) falls the same way, because the relabelling keeps the order. The tables come from the
site's routes (:attr:`GraphSpec.routes`): the all-pairs tables' columns up to 500 nodes, one
breadth-first search per target above.
"""

from __future__ import annotations

import numpy as np

from sb3_pm.graphs import GraphSpec

__all__ = ["TargetTables"]


class TargetTables:
    """The ``(N, T)`` tables of one site, in labels (module docstring).

    :param graph: the site.
    :ivar label: ``(N,)`` int64, each node's label.
    :ivar node: ``(N,)`` int64, each label's node (the inverse of ``label``).
    :ivar distances: ``(N, T)`` int64, ``distances[label(v), k]``: hops from ``v`` to target ``k``.
    :ivar next_hop: ``(N, T)`` int64, the label of the first node after ``v`` on a shortest path to
        target ``k`` (the smallest-index neighbour among equally short options; ``v`` itself at ``k``).
    :ivar between: ``(T, T)`` int64 hop distances between the targets.
    """

    def __init__(self, graph: GraphSpec) -> None:
        targets = np.asarray(graph.target_indices, dtype=np.int64)
        n_nodes, n_targets = graph.n_nodes, targets.size
        is_target = np.zeros(n_nodes, dtype=bool)
        is_target[targets] = True
        self.node = np.concatenate([targets, np.flatnonzero(~is_target)]).astype(np.int64)
        self.label = np.empty(n_nodes, dtype=np.int64)
        self.label[self.node] = np.arange(n_nodes)
        routes = graph.routes  # all-pairs tables on small sites, one search per target on large ones
        to_targets = routes.to_targets(np.arange(n_nodes)).astype(np.int64)  # (N, T) in node order
        hops = routes.next_hops_to_targets()
        self.distances = np.ascontiguousarray(to_targets[self.node])
        self.next_hop = np.ascontiguousarray(self.label[hops[self.node]])
        self.between = np.ascontiguousarray(self.distances[:n_targets])

    def labels(self, nodes: np.ndarray) -> np.ndarray:
        """The labels of ``nodes`` (any shape)."""
        return self.label[np.asarray(nodes, dtype=np.int64)]  # type: ignore[no-any-return]

    def nodes(self, labels: tuple[int, ...]) -> tuple[int, ...]:
        """The nodes of ``labels``, in the same order."""
        return tuple(int(self.node[label]) for label in labels)

