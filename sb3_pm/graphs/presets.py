"""Graphs by name: the paper's three published graphs (shipped inside the package) and seeded draws.

``paper-50``, ``paper-100`` and ``paper-200`` are the GraphML files the paper's authors published
for their three experiment sizes, read from ``sb3_pm/graphs/data/``; nothing is downloaded. The
``er-*`` presets are our own seeded Erdős–Rényi G(N, 0.2) draws with the paper's sizes and target
counts (the paper's text asks for 32 targets at 200 nodes; the published 200-node graph has 41).
The family presets (``rgg-60``, ``rooms-4``, ``cliques-6x8``, ``karate``) are our suite of other
structures (:mod:`sb3_pm.graphs.families`). The large-site presets (``city-1k`` to
``campus-5k``, :data:`LARGE_PRESETS`) are seeded sites of 1,000 to 20,000 nodes
(:mod:`sb3_pm.graphs.large_sites`).
"""

from __future__ import annotations

from collections.abc import Callable
from functools import cache
from pathlib import Path

from sb3_pm.graphs import families
from sb3_pm.graphs.generators import erdos_renyi
from sb3_pm.graphs.io import load_graphml
from sb3_pm.graphs.large_sites import campus, city_streets, warehouse
from sb3_pm.graphs.spec import GraphError, GraphSpec

#: Folder of the shipped GraphML files.
DATA_DIR = Path(__file__).resolve().parent / "data"

#: Preset name -> file in :data:`DATA_DIR`: the paper's published graphs.
PUBLISHED: dict[str, str] = {
    "paper-50": "paper_50n_8t.graphml",
    "paper-100": "paper_100n_17t.graphml",
    "paper-200": "paper_200n_41t.graphml",
}

#: Preset name -> (nodes, targets, seed) of a G(N, 0.2) draw. The seeds are ours.
ER_PRESETS: dict[str, tuple[int, int, int]] = {
    "er-50": (50, 8, 50),
    "er-100": (100, 17, 100),
    "er-200": (200, 32, 200),
}

#: Preset name -> builder of a graph from another family (:mod:`sb3_pm.graphs.families`): our suite
#: of structures unlike the paper's dense, small-diameter graphs. The seeds are ours.
FAMILY_PRESETS: dict[str, Callable[[str], GraphSpec]] = {
    "rgg-60": lambda name: families.random_geometric(60, 0.2, n_targets=10, seed=60, name=name),
    "rooms-4": lambda name: families.rooms(4, (4, 3), n_targets=8, seed=4, name=name),
    "cliques-6x8": lambda name: families.ring_of_cliques(6, 8, n_targets=8, seed=6, name=name),
    "karate": lambda name: _karate(name),
    "small-world-60": lambda name: families.small_world(60, 4, 0.1, n_targets=10, seed=61, name=name),
    "tree-50": lambda name: families.random_tree(50, n_targets=8, seed=51, name=name),
}


#: Preset name -> builder of a large site (:mod:`sb3_pm.graphs.large_sites`), 1,000 nodes and more,
#: one target per 10 nodes. Kept apart from :data:`FAMILY_PRESETS` because of their size: a
#: :class:`GraphSpec` stores its adjacency as an ``(N, N)`` array (400 MB at 20,000 nodes; building
#: ``city-20k`` peaks at about 1.3 GB) and an environment adds more ``(N, N)`` arrays (hop
#: distances, next hops), so code that builds every preset in a loop (as the tests do) leaves these
#: out. The seeds are ours.
LARGE_PRESETS: dict[str, Callable[[str], GraphSpec]] = {
    "city-1k": lambda name: city_streets(1000, seed=1000, name=name),
    "city-5k": lambda name: city_streets(5000, seed=5000, name=name),
    "city-20k": lambda name: city_streets(20000, seed=20000, name=name),
    "warehouse-1k": lambda name: warehouse(1000, seed=1000, name=name),
    "warehouse-5k": lambda name: warehouse(5000, seed=5000, name=name),
    "campus-1k": lambda name: campus(1000, seed=1000, name=name),
    "campus-5k": lambda name: campus(5000, seed=5000, name=name),
}


def _karate(name: str) -> GraphSpec:
    import networkx as nx

    return families.from_networkx(nx.karate_club_graph(), n_targets=6, seed=34, name=name)


#: Every preset name -> a one-line description (for ``--help`` and error messages).
PRESETS: dict[str, str] = {
    "paper-50": "the paper's published 50-node graph, 8 targets",
    "paper-100": "the paper's published 100-node graph, 17 targets",
    "paper-200": "the paper's published 200-node graph, 41 targets",
    "er-50": "a seeded Erdős–Rényi G(50, 0.2) draw, 8 targets",
    "er-100": "a seeded Erdős–Rényi G(100, 0.2) draw, 17 targets",
    "er-200": "a seeded Erdős–Rényi G(200, 0.2) draw, 32 targets",
    "rgg-60": "a seeded random geometric graph, 60 nodes, radius 0.2 (diameter 15), 10 targets",
    "rooms-4": "4 rooms of 4x3 cells (Algorithm 1) joined in a row by single doors, 48 nodes, 8 targets",
    "cliques-6x8": "a ring of 6 cliques of 8 nodes joined by single edges, 8 targets",
    "karate": "Zachary's karate club (a real social network, 34 nodes), 6 targets",
    "small-world-60": "a seeded Watts-Strogatz ring of 60 nodes, 4 neighbours each, 10% rewired, 10 targets",
    "tree-50": "a seeded uniformly random tree of 50 nodes, 8 targets",
    "city-1k": "a seeded city street grid with parks and diagonal avenues, 1,000 nodes, 100 targets",
    "city-5k": "a seeded city street grid with parks and diagonal avenues, 5,000 nodes, 500 targets",
    "city-20k": "a seeded city street grid with parks and diagonal avenues, 20,000 nodes, 2,000 targets",
    "warehouse-1k": "a seeded warehouse floor, 20 aisles of 45 places, 1,000 nodes, 100 targets",
    "warehouse-5k": "a seeded warehouse floor, 48 aisles of 100 places, 5,000 nodes, 500 targets",
    "campus-1k": "a seeded campus of buildings of rooms joined by footpaths, 1,000 nodes, 100 targets",
    "campus-5k": "a seeded campus of buildings of rooms joined by footpaths, 5,000 nodes, 500 targets",
}


def published_graph_path(name: str) -> Path:
    """The shipped GraphML file of a published preset (``paper-50``, ``paper-100``, ``paper-200``).

    :raises GraphError: for another name.
    """
    if name not in PUBLISHED:
        raise GraphError(f"{name!r} is not a published graph; those are {sorted(PUBLISHED)}")
    return DATA_DIR / PUBLISHED[name]


@cache
def preset(name: str) -> GraphSpec:
    """A preset graph by name (see :data:`PRESETS`).

    Cached: a :class:`GraphSpec` is immutable, and parsing the 200-node GraphML file is the slow
    part of building an environment on it.

    :raises GraphError: for an unknown name.
    """
    if name in PUBLISHED:
        return load_graphml(published_graph_path(name), name=name)
    if name in ER_PRESETS:
        n_nodes, n_targets, seed = ER_PRESETS[name]
        return erdos_renyi(n_nodes, edge_prob=0.2, n_targets=n_targets, seed=seed, name=name)
    if name in FAMILY_PRESETS:
        return FAMILY_PRESETS[name](name)
    if name in LARGE_PRESETS:
        return LARGE_PRESETS[name](name)
    raise GraphError(f"unknown graph preset {name!r}; presets are {sorted(PRESETS)}")
