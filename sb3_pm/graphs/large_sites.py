"""Large monitoring sites (a thousand nodes and more), drawn by seeded generators.

The paper's graphs have at most 200 nodes; robots patrol streets, warehouse floors and campuses
of thousands of places. Each generator here returns a connected :class:`GraphSpec` of exactly
``n_nodes`` nodes, with drawing ``positions`` and targets chosen by the seed:

* :func:`city_streets`: a perturbed street grid with parks (removed blocks), some closed street
  segments and a few long diagonal avenues; mean degree about 3.7;
* :func:`warehouse`: parallel aisles (long paths) joined by cross-aisles at both ends and at a
  few midpoints; the targets are shelf places in the aisles;
* :func:`campus`: buildings (Algorithm 1 boxes of rooms, as :func:`~sb3_pm.graphs.families.rooms`)
  joined by footpaths, so a few edges cut each building from the rest.

Sizes: by default one node in :data:`NODES_PER_TARGET` is a target; we suggest one agent per
:data:`NODES_PER_AGENT` nodes (:func:`suggested_agents`). Each generator builds its graph from
edge lists and never from an ``(N, N)`` matrix; only the returned :class:`GraphSpec` stores its
adjacency densely (400 MB at 20,000 nodes), and its derived ``hop_distances``, ``next_hop`` and
``reachable`` (computed on first use) are ``(N, N)`` too, so use them on large sites with care.
"""

from __future__ import annotations

import math
from functools import cache

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components, minimum_spanning_tree

from sb3_pm.graphs.generators import hyperrectangle
from sb3_pm.graphs.spec import GraphError, GraphSpec

#: Default target density: one target per this many nodes.
NODES_PER_TARGET = 10
#: Suggested team size: one agent per this many nodes.
NODES_PER_AGENT = 80


def suggested_agents(n_nodes: int) -> int:
    """The team size we suggest for a site of ``n_nodes`` nodes: one agent per
    :data:`NODES_PER_AGENT` nodes, at least one."""
    return max(1, n_nodes // NODES_PER_AGENT)


def _n_targets(n_nodes: int, n_targets: int | None, n_candidates: int) -> int:
    count = max(1, n_nodes // NODES_PER_TARGET) if n_targets is None else n_targets
    if not 1 <= count <= n_candidates:
        raise GraphError(f"n_targets must be in [1, {n_candidates}], got {count}")
    return count


def _spec(
    n_nodes: int,
    edges: np.ndarray,
    positions: np.ndarray,
    candidates: np.ndarray,
    n_targets: int,
    rng: np.random.Generator,
    name: str,
) -> GraphSpec:
    """The :class:`GraphSpec` of an ``(E, 2)`` edge list, ``n_targets`` targets drawn from ``candidates``."""
    flags = np.zeros(n_nodes, dtype=bool)
    flags[rng.choice(candidates, size=n_targets, replace=False)] = True
    adjacency = np.zeros((n_nodes, n_nodes), dtype=bool)  # GraphSpec's storage is dense
    adjacency[edges[:, 0], edges[:, 1]] = True
    adjacency[edges[:, 1], edges[:, 0]] = True
    return GraphSpec(adjacency=adjacency, targets=flags, name=name, positions=positions)


def _sparse(n_nodes: int, edges: np.ndarray, weights: np.ndarray | None = None) -> coo_matrix:
    data = np.ones(len(edges)) if weights is None else weights
    return coo_matrix((data, (edges[:, 0], edges[:, 1])), shape=(n_nodes, n_nodes))


def _join_components(edges: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """``edges`` plus, for each component but node 0's, one edge between its nearest pair of nodes
    and node 0's component (a road across whatever separated them)."""
    n_nodes = len(positions)
    n_components, labels = connected_components(_sparse(n_nodes, edges), directed=False)
    if n_components == 1:
        return edges
    from scipy.spatial import cKDTree

    main = np.flatnonzero(labels == labels[0])
    tree = cKDTree(positions[main])
    bridges = []
    for component in range(n_components):
        if component == labels[0]:
            continue
        members = np.flatnonzero(labels == component)
        distances, nearest = tree.query(positions[members])
        best = int(np.argmin(distances))
        bridges.append((members[best], main[nearest[best]]))
    return np.concatenate([edges, np.array(bridges, dtype=np.int64)])


def _lattice_edges(index: np.ndarray) -> np.ndarray:
    """4-neighbour edges between the kept cells (``index >= 0``) of a 2-D cell-index grid."""
    pairs = []
    for a, b in ((index[:, :-1], index[:, 1:]), (index[:-1, :], index[1:, :])):
        both = (a >= 0) & (b >= 0)
        pairs.append(np.stack([a[both], b[both]], axis=1))
    return np.concatenate(pairs).astype(np.int64)


def _check_fraction(label: str, value: float, upper: float) -> None:
    if not 0.0 <= value < upper:
        raise GraphError(f"{label} must be in [0, {upper:g}), got {value}")


def city_streets(
    n_nodes: int,
    n_targets: int | None = None,
    park_fraction: float = 0.08,
    closed_streets: float = 0.12,
    n_avenues: int | None = None,
    jitter: float = 0.2,
    seed: int = 0,
    name: str | None = None,
) -> GraphSpec:
    """A city's street network: crossings on a perturbed grid, joined by streets.

    Crossings sit on a square grid (jittered by up to ``jitter`` of a block) from which rectangular
    parks of 2 to 5 blocks a side are removed, about ``park_fraction`` of the area; the first
    ``n_nodes`` crossings in row order are kept (the last row is partial). Neighbouring crossings
    are joined by streets, of which ``closed_streets`` are then closed at random (never one that a
    seeded spanning tree needs); ``n_avenues`` long diagonal avenues (default: one per 10 grid
    columns) cross the grid. Anything cut off is joined by one road to the nearest crossing. The
    graph is connected and planar but where two avenues cross; its mean degree is about 3.7.

    Targets: ``n_targets`` crossings (default one per :data:`NODES_PER_TARGET` nodes); we suggest
    one agent per :data:`NODES_PER_AGENT` nodes (:func:`suggested_agents`).

    :param n_nodes: number of crossings (at least 16).
    :param seed: seed of the only random generator used (parks, jitter, closures, avenues, targets).
    :raises GraphError: for too few nodes, fractions out of range or too many targets.
    """
    if n_nodes < 16:
        raise GraphError(f"city_streets needs at least 16 nodes, got {n_nodes}")
    _check_fraction("park_fraction", park_fraction, 0.5)
    _check_fraction("closed_streets", closed_streets, 0.5)
    _check_fraction("jitter", jitter, 0.5)
    if n_avenues is not None and n_avenues < 0:
        raise GraphError(f"n_avenues must be at least 0, got {n_avenues}")
    count = _n_targets(n_nodes, n_targets, n_nodes)
    rng = np.random.default_rng(seed)
    cols = math.ceil(math.sqrt(n_nodes / (1.0 - park_fraction)))
    rows = 2 * cols + 2  # park-free rows below the parks guarantee n_nodes crossings
    park = np.zeros((rows, cols), dtype=bool)
    wanted, area, tries = park_fraction * cols * cols, 0, 0
    while area < wanted and tries < 50 * cols:
        tries += 1
        height, width = rng.integers(2, 6, size=2)
        top, left = int(rng.integers(1, max(2, cols - height))), int(rng.integers(1, max(2, cols - width)))
        if top + height > cols - 1 or left + width > cols - 1:
            continue
        if not park[top - 1 : top + height + 1, left - 1 : left + width + 1].any():  # parks never touch
            park[top : top + height, left : left + width] = True
            area += int(height * width)
    kept = np.flatnonzero(~park.ravel())[:n_nodes]
    index = np.full(rows * cols, -1, dtype=np.int64)
    index[kept] = np.arange(n_nodes)
    index = index.reshape(rows, cols)
    r, c = np.divmod(kept, cols)
    positions = np.stack([c, -r], axis=1) + rng.uniform(-jitter, jitter, size=(n_nodes, 2))
    streets = _join_components(_lattice_edges(index), positions)
    # Close streets off a seeded random spanning tree, so closing never disconnects the city.
    tree = minimum_spanning_tree(_sparse(n_nodes, streets, rng.uniform(1.0, 2.0, len(streets))))
    tree = tree.tocoo()
    keys = np.minimum(streets[:, 0], streets[:, 1]) * n_nodes + np.maximum(streets[:, 0], streets[:, 1])
    needed = np.isin(keys, np.minimum(tree.row, tree.col) * n_nodes + np.maximum(tree.row, tree.col))
    streets = streets[needed | (rng.random(len(streets)) >= closed_streets)]
    avenues = []
    for _ in range(cols // 10 if n_avenues is None else n_avenues):
        step = 1 if rng.random() < 0.5 else -1  # the avenue runs down and right (1) or left (-1)
        if rng.random() < 0.5:  # from the top row's first (or last) half, across the city
            row, col = 0, int(rng.integers(cols // 2)) + (0 if step == 1 else cols - cols // 2)
        else:  # from the upper half of the side it runs away from
            row, col = int(rng.integers(max(1, r[-1] // 2))), 0 if step == 1 else cols - 1
        while 0 <= row + 1 < rows and 0 <= col + step < cols:
            a, b = index[row, col], index[row + 1, col + step]
            if a >= 0 and b >= 0:
                avenues.append((a, b))
            row, col = row + 1, col + step
    if avenues:
        streets = np.concatenate([streets, np.array(avenues, dtype=np.int64)])
    label = name or f"city-{n_nodes}-s{seed}"
    return _spec(n_nodes, streets, positions, np.arange(n_nodes), count, rng, label)


def warehouse(
    n_nodes: int,
    n_targets: int | None = None,
    aisle_length: int | None = None,
    n_cross_aisles: int = 2,
    seed: int = 0,
    name: str | None = None,
) -> GraphSpec:
    """A warehouse floor: parallel aisles joined by cross-aisles.

    Each aisle is a path of ``aisle_length`` places (default about ``sqrt(2 n_nodes)``) between two
    racks. Cross-aisles run along the front row, the back row and ``n_cross_aisles`` middle rows
    drawn by the seed; between two neighbouring aisles a cross-aisle passes one place of its own.
    The places left over after the last full aisle form a dead-end aisle open at the front (or,
    for a single place, a dock before the first aisle). Most places have degree 2.

    Targets: ``n_targets`` shelf places (aisle places off the cross-aisles), default one per
    :data:`NODES_PER_TARGET` nodes; we suggest one agent per :data:`NODES_PER_AGENT` nodes
    (:func:`suggested_agents`).

    :param n_nodes: number of places; there must be room for at least 2 full aisles.
    :param seed: seed of the only random generator used (the middle cross-aisles and the targets).
    :raises GraphError: for too few nodes for two aisles, bad aisle length or cross-aisle count,
        or more targets than shelf places.
    """
    length = max(4, round(math.sqrt(2 * n_nodes))) if aisle_length is None else aisle_length
    if length < 3:
        raise GraphError(f"aisle_length must be at least 3, got {length}")
    if not 0 <= n_cross_aisles <= length - 3:  # leave a shelf row
        raise GraphError(f"n_cross_aisles must be in [0, {length - 3}], got {n_cross_aisles}")
    n_cross = n_cross_aisles + 2
    n_aisles = (n_nodes + n_cross) // (length + n_cross)
    if n_aisles < 2:
        raise GraphError(
            f"warehouse needs room for 2 aisles of {length} places: at least "
            f"{2 * length + n_cross} nodes, got {n_nodes}"
        )
    rng = np.random.default_rng(seed)
    # Middle cross-aisles: evenly spaced (spacing >= 1), each moved by up to a quarter of the
    # spacing, so they stay distinct and strictly between the front and back rows.
    spacing = (length - 1) / (n_cross_aisles + 1)
    shift = rng.integers(-int(spacing // 4), int(spacing // 4) + 1, size=n_cross_aisles)
    middles = np.round(spacing * np.arange(1, n_cross_aisles + 1)) + shift
    cross_rows = np.concatenate([[0, length - 1], middles]).astype(np.int64)
    # Aisle a's place in row y is node a * length + y; the cross places follow the aisles.
    aisle = np.arange(n_aisles * length, dtype=np.int64).reshape(n_aisles, length)
    shelf = np.ones((n_aisles, length), dtype=bool)
    shelf[:, cross_rows] = False
    edges = [np.stack([aisle[:, :-1].ravel(), aisle[:, 1:].ravel()], axis=1)]
    xs, ys = np.meshgrid(2.0 * np.arange(n_aisles), np.arange(length), indexing="ij")
    positions = [np.stack([xs.ravel(), ys.ravel()], axis=1)]
    gaps = np.arange(n_aisles - 1)
    cross = n_aisles * length + np.arange(len(gaps) * n_cross, dtype=np.int64).reshape(n_cross, len(gaps))
    for k, row in enumerate(cross_rows):
        edges.append(np.stack([aisle[gaps, row], cross[k]], axis=1))
        edges.append(np.stack([cross[k], aisle[gaps + 1, row]], axis=1))
        positions.append(np.stack([2.0 * gaps + 1.0, np.full(len(gaps), float(row))], axis=1))
    shelves = [aisle[shelf]]
    used = n_aisles * length + (n_aisles - 1) * n_cross
    rest = n_nodes - used
    if rest == 1:  # a dock before the first aisle's front
        edges.append(np.array([[aisle[0, 0], used]]))
        positions.append(np.array([[0.0, -1.0]]))
    elif rest > 1:  # a dead-end aisle: a cross place at the front, then rest - 1 places
        partial = used + np.arange(rest, dtype=np.int64)
        edges.append(np.array([[aisle[-1, 0], partial[0]]]))
        edges.append(np.stack([partial[:-1], partial[1:]], axis=1))
        positions.append(np.array([[2.0 * n_aisles - 1.0, 0.0]]))
        positions.append(np.stack([np.full(rest - 1, 2.0 * n_aisles), np.arange(rest - 1.0)], axis=1))
        shelves.append(partial[2:])
    candidates = np.concatenate(shelves)
    count = _n_targets(n_nodes, n_targets, len(candidates))
    label = name or f"warehouse-{n_nodes}-s{seed}"
    return _spec(n_nodes, np.concatenate(edges), np.concatenate(positions), candidates, count, rng, label)


@cache
def _building(width: int, depth: int) -> tuple[np.ndarray, np.ndarray]:
    """The edges and cell centres of a ``width x depth`` Algorithm 1 box of rooms (cell ``i * depth + j``)."""
    box = hyperrectangle(lengths=(width, depth), chunk_sizes=(1, 1), targets=[0])
    assert box.positions is not None
    return np.argwhere(np.triu(box.adjacency)), box.positions - 0.5


def _door(cells: np.ndarray, side: str, rng: np.random.Generator) -> int:
    """A random cell (row of ``cells``, an ``(k, 2)`` array of cell coordinates) on one side."""
    axis, pick = {"left": (0, np.min), "right": (0, np.max), "front": (1, np.min), "back": (1, np.max)}[side]
    return int(rng.choice(np.flatnonzero(cells[:, axis] == pick(cells[:, axis]))))


def _campus_layout(
    n_nodes: int,
    building_size: tuple[int, int],
    footpath_length: tuple[int, int],
    extra_paths: float,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Edges, positions and each node's building (``-1`` on a footpath) of a campus; see :func:`campus`."""
    low, high = building_size
    short, long = footpath_length
    per_plot = ((low + high) / 2) ** 2 + (short + long) / 2 * (1 + extra_paths)
    width = max(1, math.ceil(math.sqrt(n_nodes / per_plot)))
    pitch = high + 2.0
    edges: list[np.ndarray] = []
    positions: list[np.ndarray] = []
    labels: list[np.ndarray] = []
    built: list[tuple[int, np.ndarray, np.ndarray]] = []  # each building's first node, cells, positions
    used, plot = 0, 0
    while used < n_nodes:
        row, col = divmod(plot, width)
        links = [side for side, there in (("left", col > 0), ("back", row > 0)) if there]
        rng.shuffle(links)  # links[0] is the footpath that joins the building to the campus
        lengths = [int(rng.integers(short, long + 1)) for _ in links]
        if len(links) == 2 and rng.random() >= extra_paths:
            links, lengths = links[:1], lengths[:1]
        w, d = (int(v) for v in rng.integers(low, high + 1, size=2))
        rest = n_nodes - used
        if w * d + sum(lengths) > rest and len(links) == 2:  # drop the loop before shrinking
            links, lengths = links[:1], lengths[:1]
        if w * d + sum(lengths) > rest and links:  # the last building: as many cells as fit
            lengths = [min(lengths[0], rest - 1)]
        n_cells = min(w * d, rest - sum(lengths))
        box_edges, box_cells = _building(w, d)
        cells = box_cells[:n_cells]  # a prefix in C order of a box is connected
        start = used
        edges.append(start + box_edges[(box_edges < n_cells).all(axis=1)])
        placed = np.array([col * pitch, -row * pitch]) + cells
        positions.append(placed)
        labels.append(np.full(n_cells, plot))
        used += n_cells
        for side, length in zip(links, lengths):
            neighbour = plot - 1 if side == "left" else plot - width
            other_start, other_cells, other_placed = built[neighbour]
            mine = start + _door(cells, side, rng)
            theirs = other_start + _door(other_cells, "right" if side == "left" else "front", rng)
            path = np.arange(used, used + length, dtype=np.int64)
            chain = np.concatenate([[mine], path, [theirs]])
            edges.append(np.stack([chain[:-1], chain[1:]], axis=1))
            ends = np.array([placed[mine - start], other_placed[theirs - other_start]])
            steps = (np.arange(1, length + 1) / (length + 1))[:, None]
            positions.append(ends[0] + steps * (ends[1] - ends[0]))
            labels.append(np.full(length, -1))
            used += length
        built.append((start, cells, placed))
        plot += 1
    return np.concatenate(edges).astype(np.int64), np.concatenate(positions), np.concatenate(labels)


def campus(
    n_nodes: int,
    n_targets: int | None = None,
    building_size: tuple[int, int] = (3, 6),
    footpath_length: tuple[int, int] = (1, 4),
    extra_paths: float = 0.3,
    seed: int = 0,
    name: str | None = None,
) -> GraphSpec:
    """A campus: buildings of rooms joined by footpaths.

    Buildings stand on a square grid of plots, filled row by row. Each is an Algorithm 1 box of
    rooms (as in :func:`~sb3_pm.graphs.families.rooms`; rooms touching at a face, edge or corner
    are joined) with sides drawn from ``building_size`` (inclusive). A footpath of
    ``footpath_length`` places (inclusive range) joins a door of each building to the building on
    its left or behind it, and with probability ``extra_paths`` to the other one too, closing a
    loop. So at most four footpaths leave a building: each one is a small cut. The last building
    takes as many rooms as fit in ``n_nodes``.

    Targets: ``n_targets`` rooms (footpath places are never targets), default one per
    :data:`NODES_PER_TARGET` nodes; we suggest one agent per :data:`NODES_PER_AGENT` nodes
    (:func:`suggested_agents`).

    :param n_nodes: number of places (rooms and footpath places), at least ``2 * building_size[1]**2``.
    :param seed: seed of the only random generator used.
    :raises GraphError: for too few nodes, bad sizes or probability, or more targets than rooms.
    """
    low, high = building_size
    short, long = footpath_length
    if not 2 <= low <= high:
        raise GraphError(f"building_size must be (low, high) with 2 <= low <= high, got {building_size}")
    if not 0 <= short <= long:
        raise GraphError(f"footpath_length must be (low, high) with 0 <= low <= high, got {footpath_length}")
    if not 0.0 <= extra_paths <= 1.0:
        raise GraphError(f"extra_paths must be in [0, 1], got {extra_paths}")
    if n_nodes < 2 * high**2:
        raise GraphError(
            f"campus needs at least {2 * high**2} nodes for buildings of side {high}, got {n_nodes}"
        )
    rng = np.random.default_rng(seed)
    edges, positions, labels = _campus_layout(n_nodes, building_size, footpath_length, extra_paths, rng)
    rooms_ = np.flatnonzero(labels >= 0)
    count = _n_targets(n_nodes, n_targets, len(rooms_))
    label = name or f"campus-{n_nodes}-s{seed}"
    return _spec(n_nodes, edges, positions, rooms_, count, rng, label)
