"""One plan search in a process of its own, for :func:`~sb3_pm.planning.planner.plan_both_ways`.

``python -m sb3_pm.planning.search_worker`` reads a search's request from standard input and writes
the plan to standard output, both as plain state (:mod:`sb3_pm.plain_state`: JSON and arrays, read
with ``allow_pickle=False``, so neither side can be made to run code). A worker started this way
imports nothing of its caller's script, as a ``multiprocessing`` spawn would.
"""

from __future__ import annotations

import dataclasses
import sys
from typing import Any

import numpy as np

from sb3_pm.graphs import GraphSpec
from sb3_pm.plain_state import state_bytes, state_from_bytes
from sb3_pm.planning.planner import PatrolPlan, plan_patrol


def request(graph: GraphSpec, arguments: dict[str, Any]) -> bytes:
    """The request for :func:`plan_patrol` on ``graph`` with keyword ``arguments``: the graph as its
    edge list and target flags (``(2, E)`` and ``(N,)``), the arguments as they are."""
    edges = graph.sparse_adjacency.tocoo()
    site = {"n_nodes": graph.n_nodes, "rows": edges.row, "cols": edges.col, "targets": graph.targets}
    return state_bytes({"graph": {**site, "name": graph.name}, "arguments": arguments})


def answer(data: bytes) -> bytes:
    """The plan, as plain state, for a :func:`request`."""
    message = state_from_bytes(data)
    site = message["graph"]
    adjacency = np.zeros((site["n_nodes"], site["n_nodes"]), dtype=bool)
    adjacency[site["rows"], site["cols"]] = True
    graph = GraphSpec(adjacency, site["targets"], name=site["name"])
    plan = plan_patrol(graph, **message["arguments"])
    return state_bytes({field.name: getattr(plan, field.name) for field in dataclasses.fields(plan)})


def plan_from(data: bytes) -> PatrolPlan:
    """The plan of an :func:`answer`."""
    return PatrolPlan(**state_from_bytes(data))


def main() -> None:
    sys.stdout.buffer.write(answer(sys.stdin.buffer.read()))


if __name__ == "__main__":
    main()
