"""Graphs for persistent monitoring: one immutable :class:`GraphSpec`, its generators and GraphML I/O."""

from sb3_pm.graphs.generators import PRESETS, erdos_renyi, hyperrectangle, preset
from sb3_pm.graphs.io import load_graphml, save_graphml
from sb3_pm.graphs.resolve import GraphLike, graph_label, resolve_graph
from sb3_pm.graphs.spec import GraphError, GraphSpec

__all__ = [
    "PRESETS",
    "GraphError",
    "GraphLike",
    "GraphSpec",
    "erdos_renyi",
    "graph_label",
    "hyperrectangle",
    "load_graphml",
    "preset",
    "resolve_graph",
    "save_graphml",
]
