"""Graphs for persistent monitoring: one immutable :class:`GraphSpec`, its generators, GraphML I/O,
seeded graph families to train on (:mod:`sb3_pm.graphs.distributions`) and large sites
(:mod:`sb3_pm.graphs.large_sites`)."""

from sb3_pm.graphs.distributions import FAMILY_NAMES, GraphFamily, family_from_record, resolve_family
from sb3_pm.graphs.families import (
    from_networkx,
    random_geometric,
    random_tree,
    ring_of_cliques,
    rooms,
    small_world,
)
from sb3_pm.graphs.generators import erdos_renyi, hyperrectangle
from sb3_pm.graphs.io import load_graphml, save_graphml
from sb3_pm.graphs.large_sites import campus, city_streets, suggested_agents, warehouse
from sb3_pm.graphs.presets import (
    ER_PRESETS,
    FAMILY_PRESETS,
    LARGE_PRESETS,
    PRESETS,
    PUBLISHED,
    preset,
    published_graph_path,
)
from sb3_pm.graphs.resolve import GraphLike, graph_label, resolve_graph, resolve_graph_or_family
from sb3_pm.graphs.spec import GraphError, GraphSpec

__all__ = [
    "ER_PRESETS",
    "FAMILY_NAMES",
    "FAMILY_PRESETS",
    "LARGE_PRESETS",
    "PRESETS",
    "PUBLISHED",
    "GraphError",
    "GraphFamily",
    "GraphLike",
    "GraphSpec",
    "campus",
    "city_streets",
    "erdos_renyi",
    "family_from_record",
    "from_networkx",
    "graph_label",
    "hyperrectangle",
    "load_graphml",
    "preset",
    "published_graph_path",
    "random_geometric",
    "random_tree",
    "resolve_family",
    "resolve_graph",
    "resolve_graph_or_family",
    "ring_of_cliques",
    "rooms",
    "save_graphml",
    "small_world",
    "suggested_agents",
    "warehouse",
]
