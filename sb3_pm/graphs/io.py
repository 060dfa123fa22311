"""GraphML reading and writing. A node attribute ``target`` (0/1) marks the targets."""

from __future__ import annotations

from pathlib import Path

import networkx as nx
import numpy as np

from sb3_pm.files import atomic_path
from sb3_pm.graphs.spec import GraphError, GraphSpec


def load_graphml(path: str | Path, name: str | None = None) -> GraphSpec:
    """Read a GraphML file into a :class:`GraphSpec`.

    Node ids may be any strings; nodes keep the file's order and the ids are stored in
    ``GraphSpec.node_ids``. Optional ``x``/``y`` attributes become drawing positions.

    :raises FileNotFoundError: if the file does not exist.
    :raises GraphError: if the file is not GraphML, a node lacks a 0/1 ``target``, the graph is
        directed with asymmetric edges, disconnected, or has no targets.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"graph file not found: {path}")
    try:
        graph = nx.read_graphml(path)
    except Exception as error:  # networkx raises several parser exception types
        raise GraphError(f"{path} is not a readable GraphML file: {error}") from error
    nodes = list(graph.nodes)
    if not nodes:
        raise GraphError(f"{path} has no nodes")
    index = {node: i for i, node in enumerate(nodes)}
    targets = np.zeros(len(nodes), dtype=bool)
    for node in nodes:
        if "target" not in graph.nodes[node]:
            raise GraphError(f"{path}: node {node!r} has no 'target' attribute")
        value = graph.nodes[node]["target"]
        try:
            flag = int(value)
        except (TypeError, ValueError):
            flag = -1
        if flag not in (0, 1) or str(value).strip() not in {"0", "1", "True", "False", "true", "false"}:
            raise GraphError(f"{path}: node {node!r} has target={value!r}; expected 0 or 1")
        targets[index[node]] = bool(flag)
    if graph.is_directed():
        # A directed file is accepted only when every edge has its reverse (an undirected graph
        # written as directed); a one-way edge would be made two-way by the symmetric adjacency.
        one_way = next(((a, b) for a, b in graph.edges() if not graph.has_edge(b, a)), None)
        if one_way is not None:
            raise GraphError(
                f"{path}: directed graph with a one-way edge {one_way[0]!r} -> {one_way[1]!r}; "
                "persistent monitoring needs an undirected graph (add the reverse edges or "
                'declare edgedefault="undirected")'
            )
    adjacency = np.zeros((len(nodes), len(nodes)), dtype=bool)
    for a, b in graph.edges():
        if a == b:
            raise GraphError(f"{path}: self-loop at node {a!r}")
        adjacency[index[a], index[b]] = adjacency[index[b], index[a]] = True
    positions = None
    if all("x" in graph.nodes[n] and "y" in graph.nodes[n] for n in nodes):
        positions = np.array([[float(graph.nodes[n]["x"]), float(graph.nodes[n]["y"])] for n in nodes])
    try:
        return GraphSpec(
            adjacency=adjacency,
            targets=targets,
            name=name or path.stem,
            positions=positions,
            node_ids=tuple(str(n) for n in nodes),
        )
    except GraphError as error:
        raise GraphError(f"{path}: {error}") from error


def save_graphml(spec: GraphSpec, path: str | Path, overwrite: bool = False) -> Path:
    """Write ``spec`` as GraphML with node ids from ``spec.node_ids`` (else ``"0".."N-1"``).

    :raises FileExistsError: if ``path`` exists and ``overwrite`` is False.
    """
    path = Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists; pass overwrite=True to replace it")
    ids = spec.node_ids or tuple(str(i) for i in range(spec.n_nodes))
    graph = nx.relabel_nodes(spec.to_networkx(), dict(enumerate(ids)))
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as temporary:
        nx.write_graphml(graph, temporary)
    return path
