"""Graph families to train on: seeded distributions that draw one graph per episode.

A team trained on one graph learns that graph. To learn a patrol that transfers, an environment
built on a :class:`GraphFamily` draws a new graph at every reset, from its own seeded generator, so
the sequence of graphs flows from the environment's seed like every other draw. The families:

``family:er``
    Erdős–Rényi, N in [20, 60], edge probability in [0.1, 0.3] (raised to at least
    1.5 ln N / N, so that draws are connected: 0.225 at N = 20), 10–25% of the
    nodes targets (the paper's graphs are N = 50, p = 0.2, 16%).
``family:rgg``
    random geometric graphs, N in [30, 80], radius set for a nominal mean degree of
    7–12 (nodes near the square's edges have fewer neighbours; measured 5–10.5):
    sparse, spatial, large diameter.
``family:rooms``
    Algorithm 1 room rows, 2–5 rooms of 3–5 × 3–4 cells joined by single doors, with
    as many targets as 1–2 per room, placed uniformly over all cells.
``family:mixed``
    one of the three above, uniformly.
a folder
    every ``.graphml`` file in it, drawn uniformly (``family:DIR`` or the folder's path).

The classes are public: ``ErdosRenyiFamily(n_nodes_range=(30, 90))`` is a family with other
ranges, for the Python API. Observation spaces have a fixed size in SB3, so a family states ``max_nodes``, the
size every observation is padded to (:mod:`sb3_pm.envs.persistent_monitoring`, ``graph``).
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from sb3_pm.graphs.families import random_geometric, rooms
from sb3_pm.graphs.generators import erdos_renyi
from sb3_pm.graphs.io import load_graphml
from sb3_pm.graphs.spec import GraphError, GraphSpec

#: The prefix naming a family in ``--env`` and in configs (``family:er``).
FAMILY_PREFIX = "family:"


def _check_range(
    name: str, bounds: tuple[float, float], low: float, high: float, integer: bool = False
) -> tuple[float, float]:
    """``bounds`` as a validated ``(lo, hi)`` pair within ``[low, high]`` (of integers if asked)."""
    kinds = (int, np.integer) if integer else (int, float, np.integer, np.floating)
    if (
        not isinstance(bounds, (tuple, list))
        or len(bounds) != 2
        or not all(isinstance(v, kinds) and not isinstance(v, bool) for v in bounds)
    ):
        what = "integers" if integer else "numbers"
        raise GraphError(f"{name} must be a (low, high) pair of {what}, got {bounds!r}")
    lo, hi = bounds
    if not low <= lo <= hi <= high:
        raise GraphError(f"{name} must satisfy {low} <= low <= high <= {high}, got {tuple(bounds)}")
    return lo, hi


def _n_targets(n_nodes: int, fraction: float) -> int:
    """At least two targets (one would make the problem a single-node guard duty), at most N."""
    return int(min(n_nodes, max(2, round(fraction * n_nodes))))


@dataclass(frozen=True)
class GraphFamily:
    """A seeded distribution over graphs (subclasses say which).

    Equal families (same class and parameters) have equal :attr:`fingerprint`s; a saved team
    records its family with :meth:`record` and :func:`family_from_record` rebuilds it.
    """

    kind: ClassVar[str] = "family"
    name: str = field(default="family", kw_only=True)

    @property
    def max_nodes(self) -> int:
        """The largest graph this family draws (the padded observation size)."""
        raise NotImplementedError

    @property
    def min_nodes(self) -> int:
        """The smallest graph this family draws (a team may have at most this many agents)."""
        raise NotImplementedError

    def draw(self, rng: np.random.Generator) -> GraphSpec:
        """One graph, every random choice from ``rng``."""
        raise NotImplementedError

    def parameters(self) -> dict[str, Any]:
        """The family's parameters as JSON-ready values (without the name)."""
        values = asdict(self)
        values.pop("name")
        return values

    def record(self) -> dict[str, Any]:
        """How a saved team's manifest names this family (see :func:`family_from_record`)."""
        return {"kind": self.kind, "name": self.name, **self.parameters()}

    @property
    def fingerprint(self) -> str:
        """A short hash of the kind and parameters; never equal to a single graph's."""
        text = json.dumps({"kind": self.kind, **self.parameters()}, sort_keys=True)
        return "family-" + hashlib.sha1(text.encode()).hexdigest()[:9]

    def __str__(self) -> str:
        return self.name


@dataclass(frozen=True)
class _RandomSizeFamily(GraphFamily):
    """A family whose graphs have a node count and a target fraction uniform in their ranges."""

    n_nodes_range: tuple[int, int] = (20, 60)
    target_fraction: tuple[float, float] = (0.10, 0.25)

    def __post_init__(self) -> None:
        _check_range("n_nodes_range", self.n_nodes_range, 2, 10_000, integer=True)
        _check_range("target_fraction", self.target_fraction, 0.0, 1.0)

    @property
    def max_nodes(self) -> int:
        return int(self.n_nodes_range[1])

    @property
    def min_nodes(self) -> int:
        return int(self.n_nodes_range[0])

    def _draw_n_nodes(self, rng: np.random.Generator) -> int:
        return int(rng.integers(self.n_nodes_range[0], self.n_nodes_range[1], endpoint=True))

    def _draw_n_targets(self, rng: np.random.Generator, n_nodes: int) -> int:
        return _n_targets(n_nodes, float(rng.uniform(*self.target_fraction)))


@dataclass(frozen=True)
class ErdosRenyiFamily(_RandomSizeFamily):
    """Connected G(N, p) draws with N, p and the target fraction uniform in their ranges."""

    kind: ClassVar[str] = "erdos_renyi"
    edge_prob: tuple[float, float] = (0.1, 0.3)

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_range("edge_prob", self.edge_prob, 1e-9, 1.0)

    def draw(self, rng: np.random.Generator) -> GraphSpec:
        n_nodes = self._draw_n_nodes(rng)
        # Below ln(N)/N a G(N, p) draw is rarely connected: keep p above it so redraws stay few.
        p = max(float(rng.uniform(*self.edge_prob)), 1.5 * math.log(n_nodes) / n_nodes)
        n_targets = self._draw_n_targets(rng, n_nodes)
        return erdos_renyi(n_nodes, min(p, 1.0), n_targets=n_targets, seed=int(rng.integers(2**31)))


@dataclass(frozen=True)
class RandomGeometricFamily(_RandomSizeFamily):
    """Random geometric graphs: N uniform, radius for a mean degree uniform in ``degree``."""

    kind: ClassVar[str] = "random_geometric"
    n_nodes_range: tuple[int, int] = (30, 80)
    degree: tuple[float, float] = (7.0, 12.0)

    def __post_init__(self) -> None:
        super().__post_init__()
        # Below a mean degree of about 4 a random geometric graph is almost never connected.
        _check_range("degree", self.degree, 4.0, 10_000.0)

    def draw(self, rng: np.random.Generator) -> GraphSpec:
        n_nodes = self._draw_n_nodes(rng)
        radius = math.sqrt(float(rng.uniform(*self.degree)) / (math.pi * n_nodes))  # pi r^2 N = degree
        n_targets = self._draw_n_targets(rng, n_nodes)
        return random_geometric(n_nodes, radius, n_targets, seed=int(rng.integers(2**31)))


@dataclass(frozen=True)
class RoomsFamily(GraphFamily):
    """Rows of Algorithm 1 rooms joined by single doors; ``n_rooms`` to ``2 n_rooms`` targets, placed
    uniformly over all cells."""

    kind: ClassVar[str] = "rooms"
    n_rooms: tuple[int, int] = (2, 5)
    room_width: tuple[int, int] = (3, 5)
    room_depth: tuple[int, int] = (3, 4)

    def __post_init__(self) -> None:
        _check_range("n_rooms", self.n_rooms, 2, 1000, integer=True)
        _check_range("room_width", self.room_width, 1, 1000, integer=True)
        _check_range("room_depth", self.room_depth, 1, 1000, integer=True)

    @property
    def max_nodes(self) -> int:
        return int(self.n_rooms[1] * self.room_width[1] * self.room_depth[1])

    @property
    def min_nodes(self) -> int:
        return int(self.n_rooms[0] * self.room_width[0] * self.room_depth[0])

    def draw(self, rng: np.random.Generator) -> GraphSpec:
        n_rooms = int(rng.integers(self.n_rooms[0], self.n_rooms[1], endpoint=True))
        cells = (
            int(rng.integers(self.room_width[0], self.room_width[1], endpoint=True)),
            int(rng.integers(self.room_depth[0], self.room_depth[1], endpoint=True)),
        )
        n_targets = int(rng.integers(n_rooms, 2 * n_rooms, endpoint=True))
        return rooms(
            n_rooms, cells, min(n_targets, n_rooms * cells[0] * cells[1]), seed=int(rng.integers(2**31))
        )


@dataclass(frozen=True)
class FolderFamily(GraphFamily):
    """Every ``.graphml`` file of a folder, drawn uniformly (read once, in file-name order)."""

    kind: ClassVar[str] = "folder"
    folder: str = "."

    def __post_init__(self) -> None:
        # Absolute, so a saved team's record finds the folder from any working directory.
        object.__setattr__(self, "folder", str(Path(self.folder).expanduser().resolve()))
        path = Path(self.folder)
        if not path.is_dir():
            raise GraphError(f"graph family folder {self.folder} is not a folder")
        files = sorted(path.glob("*.graphml"))
        if not files:
            raise GraphError(f"graph family folder {self.folder} holds no .graphml file")
        object.__setattr__(self, "_graphs", tuple(load_graphml(file) for file in files))

    @property
    def graphs(self) -> tuple[GraphSpec, ...]:
        return self._graphs  # type: ignore[attr-defined,no-any-return]

    @property
    def max_nodes(self) -> int:
        return max(graph.n_nodes for graph in self.graphs)

    @property
    def min_nodes(self) -> int:
        return min(graph.n_nodes for graph in self.graphs)

    def draw(self, rng: np.random.Generator) -> GraphSpec:
        return self.graphs[int(rng.integers(len(self.graphs)))]

    @property
    def fingerprint(self) -> str:
        """The graphs' own fingerprints, so a folder's content, not its path, names the family."""
        text = ",".join(graph.fingerprint for graph in self.graphs)
        return "family-" + hashlib.sha1(text.encode()).hexdigest()[:9]


@dataclass(frozen=True)
class MixtureFamily(GraphFamily):
    """One of several families per draw, uniformly."""

    kind: ClassVar[str] = "mixture"
    members: tuple[GraphFamily, ...] = ()

    def __post_init__(self) -> None:
        if not self.members:
            raise GraphError("a mixture family needs at least one member family")

    @property
    def max_nodes(self) -> int:
        return max(member.max_nodes for member in self.members)

    @property
    def min_nodes(self) -> int:
        return min(member.min_nodes for member in self.members)

    def draw(self, rng: np.random.Generator) -> GraphSpec:
        return self.members[int(rng.integers(len(self.members)))].draw(rng)

    def parameters(self) -> dict[str, Any]:
        return {"members": [member.record() for member in self.members]}


_KINDS: dict[str, type[GraphFamily]] = {
    cls.kind: cls
    for cls in (ErdosRenyiFamily, RandomGeometricFamily, RoomsFamily, FolderFamily, MixtureFamily)
}

#: Family presets by name (without the ``family:`` prefix) -> a one-line description.
FAMILY_NAMES: dict[str, str] = {
    "er": "Erdős–Rényi, 20-60 nodes, edge probability 0.1-0.3, 10-25% targets",
    "rgg": "random geometric, 30-80 nodes, mean degree 7-12, 10-25% targets",
    "rooms": "2-5 Algorithm 1 rooms of 3-5 x 3-4 cells in a row, 1-2 targets per room",
    "mixed": "er, rgg or rooms, uniformly",
}


def family_preset(name: str) -> GraphFamily:
    """A family by preset name (``er``, ``rgg``, ``rooms``, ``mixed``; see :data:`FAMILY_NAMES`)."""
    label = FAMILY_PREFIX + name
    if name == "er":
        return ErdosRenyiFamily(name=label)
    if name == "rgg":
        return RandomGeometricFamily(name=label)
    if name == "rooms":
        return RoomsFamily(name=label)
    if name == "mixed":
        members = (
            ErdosRenyiFamily(name="family:er"),
            RandomGeometricFamily(name="family:rgg"),
            RoomsFamily(name="family:rooms"),
        )
        return MixtureFamily(members=members, name=label)
    raise GraphError(
        f"unknown graph family {label!r}: use {', '.join(FAMILY_PREFIX + n for n in FAMILY_NAMES)} "
        "or family:FOLDER (a folder of .graphml files)"
    )


def is_family_name(text: str) -> bool:
    """True for a ``family:...`` value (which :func:`resolve_family` resolves or rejects)."""
    return text.startswith(FAMILY_PREFIX)


def resolve_family(family: str | Path | GraphFamily) -> GraphFamily:
    """A family itself, a ``family:NAME`` preset, or ``family:FOLDER`` (a folder of GraphML files).

    :raises GraphError: an unknown name, or a folder that does not exist or holds no graph.
    """
    if isinstance(family, GraphFamily):
        return family
    text = str(family)
    if not is_family_name(text):
        raise GraphError(f"{text!r} is not a graph family: families are named family:NAME or family:FOLDER")
    name = text[len(FAMILY_PREFIX) :]
    if name in FAMILY_NAMES:
        return family_preset(name)
    if "/" in name or Path(name).is_dir():
        return FolderFamily(folder=name, name=text)
    return family_preset(name)  # raises, naming the presets


def family_from_record(record: dict[str, Any]) -> GraphFamily:
    """The family a saved manifest recorded with :meth:`GraphFamily.record`.

    :raises GraphError: an unknown kind or bad parameters.
    """
    values = dict(record)
    kind = values.pop("kind", None)
    if kind not in _KINDS:
        raise GraphError(f"unknown graph family kind {kind!r} in a saved record; kinds are {sorted(_KINDS)}")
    if kind == "mixture":
        values["members"] = tuple(family_from_record(member) for member in values.get("members", ()))
    else:
        values = {key: tuple(value) if isinstance(value, list) else value for key, value in values.items()}
    try:
        return _KINDS[kind](**values)
    except TypeError as error:
        raise GraphError(f"bad {kind} family record: {error}") from None


__all__ = [
    "FAMILY_NAMES",
    "FAMILY_PREFIX",
    "ErdosRenyiFamily",
    "FolderFamily",
    "GraphFamily",
    "MixtureFamily",
    "RandomGeometricFamily",
    "RoomsFamily",
    "family_from_record",
    "family_preset",
    "is_family_name",
    "resolve_family",
]
