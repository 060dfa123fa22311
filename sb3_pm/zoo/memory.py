"""The memory a graph, a team and a config need, from their sizes alone, against what the host has.

Memory grows with the square of the node count N: the graph's derived ``(N, N)`` matrices, every
agent's mental map and observation (a dense ``(N, N)`` adjacency), every learner's rollout buffer
(``(n_steps, n_envs, N, N)`` int8) and, in training, a minibatch's adjacency as floats with the
dense attention kernel's ``(B, heads, N, N)`` scores. At 20,000 nodes an evaluation of the random
policy took 9.3 GB and 168 s for 20 steps, and a training run died after 253 s asking for a 186 GiB
rollout buffer. :func:`check_memory` refuses such a run with one line before any folder is created
or any env allocated, and warns when the estimate is within reach of the limit.

With the env's ``layout: edges`` the maps, observations and stored steps count edges instead of
node pairs (:func:`training_estimate`'s ``edges``); only the graph's own adjacency stays ``N**2``.

The estimates count only the ``N**2`` terms (and the rollout buffer's ``N``-sized node features),
from sizes: nothing is allocated. They are a floor, measured close on a 20,000-node cycle
(estimated 9.6 GB for the 9.3 GB the random-policy evaluation used): the interpreter, torch and
the ``N``-sized arrays come on top.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from sb3_pm.errors import InputError

#: Bytes per node pair of a graph's derived matrices, shared by every env on it: the adjacency and
#: the reachable set (bool), the hop distances (int32) and the float64 matrix scipy computes them in.
GRAPH_BYTES_PER_PAIR = 1 + 1 + 4 + 8
#: Bytes per node pair of one env copy: its observation balls (two bool matrices) ...
ENV_BYTES_PER_PAIR = 2
#: ... and per agent: the mental map's adjacency (bool) and the observation's (int8).
AGENT_BYTES_PER_PAIR = 2
#: Node features per observation, at most (five, with the territory and advice columns).
NODE_FEATURES = 7
#: Hidden width of the first layer of SB3's default actor and critic (``net_arch`` 64).
FLAT_WIDTH = 64
#: A flat policy's first layers, in copies: parameters, gradients and Adam's two moments.
OPTIMIZER_COPIES = 4
#: Warn when an estimate passes this share of the available memory.
WARN_SHARE = 0.5


class MemoryCheckError(InputError):
    """A run whose estimated memory exceeds what the host has available."""


@dataclass(frozen=True)
class MemoryEstimate:
    """Bytes by part (``("rollout buffers", 1_000_000), ...``), largest terms only."""

    parts: tuple[tuple[str, int], ...]

    @property
    def total(self) -> int:
        return sum(size for _, size in self.parts)

    def describe(self) -> str:
        """``12.4 GiB (graph 5.2 GiB, env copies 2.0 GiB, ...)``, the parts that count."""
        shown = ", ".join(f"{name} {format_bytes(size)}" for name, size in self.parts if size)
        return f"{format_bytes(self.total)} ({shown})"


def format_bytes(size: float) -> str:
    """``1.5 GiB``, ``320 MiB``, ``12 KiB``."""
    for unit in ("B", "KiB", "MiB", "GiB"):
        if size < 1024 or unit == "GiB" and size < 1024**2:
            return f"{size:.0f} {unit}" if unit in ("B", "KiB") else f"{size:.1f} {unit}"
        size /= 1024
    return f"{size:.1f} TiB"


def env_parts(n_nodes: int, n_agents: int, copies: int, edges: int | None = None) -> list[tuple[str, int]]:
    """The graph's matrices (once) and ``copies`` env copies with ``n_agents`` maps and observations.

    :param edges: the graph's directed edges with the env's ``layout: edges``: the graph keeps only
        its ``(N, N)`` bool adjacency, and each map and observation one byte per edge.
    """
    pairs = n_nodes * n_nodes
    if edges is not None:
        return [("graph", pairs), ("env copies", copies * edges * AGENT_BYTES_PER_PAIR * n_agents)]
    per_copy = pairs * (ENV_BYTES_PER_PAIR + AGENT_BYTES_PER_PAIR * n_agents)
    return [("graph", pairs * GRAPH_BYTES_PER_PAIR), ("env copies", copies * per_copy)]


def forward_bytes(n_nodes: int, batch: int, heads: int, layers: int, dense: bool, training: bool) -> int:
    """One forward pass on ``batch`` maps: the adjacency as float32 and, with the dense kernel, each
    GAT layer's ``(batch, heads, N, N)`` float32 scores (kept for the backward pass in training, with
    the softmax of each: two per layer; one layer's at a time otherwise)."""
    pairs = n_nodes * n_nodes
    score_copies = 2 * layers if training else 1
    return batch * pairs * 4 * (1 + (heads * score_copies if dense else 0))


def training_estimate(
    n_nodes: int,
    n_agents: int,
    n_envs: int,
    n_steps: int,
    batch_size: int,
    heads: int = 4,
    layers: int = 2,
    dense_attention: bool = True,
    flat_policy: bool = False,
    learners: int | None = None,
    edges: int | None = None,
    laplacian: bool = True,
) -> MemoryEstimate:
    """What training a team needs: the graph, ``n_envs`` env copies, a rollout buffer per learner
    (``learners``, default one per agent) and the largest minibatch's forward pass.

    :param flat_policy: SB3's ``MultiInputPolicy`` instead of ``DCBFPolicy``: it flattens the
        ``(N, N)`` adjacency into its first layers, ``N**2 x 64`` weights for the actor and for the
        critic of every learner (with gradients and Adam's moments), and has no attention.
    :param edges: the graph's directed edges with the env's ``layout: edges``: a stored step holds
        the edge list and mask (three float32 per edge) instead of the adjacency, and the minibatch
        builds no ``(N, N)`` adjacency unless the dense kernel or the Laplacian encoding
        (``laplacian``) needs one.
    """
    learners = n_agents if learners is None else learners
    graph_entries = n_nodes * n_nodes if edges is None else 3 * 4 * edges  # adjacency int8, or edges
    per_step = graph_entries + n_nodes * (4 * NODE_FEATURES + 1)  # features, mask
    parts = env_parts(n_nodes, n_agents, n_envs, edges)
    parts.append(("rollout buffers", learners * n_steps * n_envs * per_step))
    dense = dense_attention and not flat_policy
    minibatch = forward_bytes(n_nodes, batch_size, heads, layers, dense, True)
    if edges is not None and not dense and not laplacian:
        minibatch = 0  # the sparse kernel on the edge list: nothing of N x N
    parts.append(("largest minibatch", minibatch))
    if flat_policy:
        weights = 2 * FLAT_WIDTH * n_nodes * n_nodes * 4 * OPTIMIZER_COPIES
        parts.append(("flat policy layers", learners * weights))
    return MemoryEstimate(tuple(parts))


def evaluation_estimate(
    n_nodes: int,
    n_agents: int,
    learned: bool,
    heads: int = 4,
    dense_attention: bool = True,
    team_envs: int = 0,
    edges: int | None = None,
) -> MemoryEstimate:
    """What evaluating a team needs: the graph, one env, and for a learned team one forward pass on
    every agent's map.

    :param team_envs: env copies a saved team builds as it loads (its training ``n_envs``).
    :param edges: the graph's directed edges with the env's ``layout: edges``: maps, observations
        and a forward pass (the sparse kernel, one map at a time) count edges, not node pairs.
    """
    parts = env_parts(n_nodes, n_agents, 1 + team_envs, edges)
    if learned:
        if edges is None:
            forward = forward_bytes(n_nodes, n_agents, heads, 1, dense_attention, False)
        else:  # an edge list (int64) and per-edge scores of every head, per map
            forward = n_agents * edges * 8 * (2 + heads)
        parts.append(("forward pass", forward))
    return MemoryEstimate(tuple(parts))


def graph_nodes(graph: Any) -> int:
    """The node count a graph or graph family makes room for (a family: its largest graph)."""
    return int(getattr(graph, "max_nodes", None) or graph.n_nodes)


def dense_attention(graph: Any, policy_kwargs: Mapping[str, Any] | None) -> bool:
    """Whether the GAT runs its dense ``(B, heads, N, N)`` kernel on ``graph``'s maps, as
    :func:`sb3_pm.policies.attention.use_dense` decides for a training minibatch (a map's adjacency
    is a subgraph of the road network's, so the road network's density bounds it)."""
    from sb3_pm.policies.attention import DENSE_MAX_SMALL, SPARSE_DENSITY  # lazy: imports torch

    backend = (policy_kwargs or {}).get("gat_backend", "auto")
    if backend != "auto":
        return bool(backend == "dense")
    n_nodes = graph_nodes(graph)
    if n_nodes <= DENSE_MAX_SMALL:
        return True
    density = getattr(graph, "density", None)  # a family has none: its graphs are sparse
    return density is not None and float(density) >= SPARSE_DENSITY


def config_estimate(config: Any, graph: Any) -> MemoryEstimate:
    """:func:`training_estimate` for a :class:`~sb3_pm.zoo.config.TrainConfig` on ``graph``: the
    largest rollout and minibatch any learner of the team takes (the algorithm's defaults, 2048
    and 64, where the config sets none)."""
    from sb3_pm.zoo.schema import KEYS

    algorithm, encoder = KEYS["algorithm"], KEYS["encoder"]
    learner_settings = [dict(config.hyperparams)]
    learner_settings += [{**config.hyperparams, **values} for values in config.per_agent().values()]
    n_steps = max(int(s.get("n_steps", algorithm["n_steps"].default)) for s in learner_settings)
    batch_size = max(int(s.get("batch_size", algorithm["batch_size"].default)) for s in learner_settings)
    policy_kwargs = config.hyperparams.get("policy_kwargs") or {}
    flat = config.policy != "DCBFPolicy"
    edges = None
    if config.env_kwargs.get("layout") == "edges" and getattr(graph, "n_edges", None) is not None:
        edges = 2 * int(graph.n_edges)
    return training_estimate(
        graph_nodes(graph),
        config.n_agents,
        config.n_envs,
        n_steps,
        batch_size,
        heads=int(policy_kwargs.get("gat_heads", encoder["gat_heads"].default)),
        layers=int(policy_kwargs.get("gat_layers", encoder["gat_layers"].default)),
        dense_attention=not flat and dense_attention(graph, policy_kwargs),
        flat_policy=flat,
        edges=edges,
        laplacian=policy_kwargs.get("laplacian", encoder["laplacian"].default) != "none",
    )


def available_memory() -> int | None:
    """Bytes the host can give a new allocation without swapping: psutil's ``available``, else
    ``/proc/meminfo``'s ``MemAvailable``, else the free physical pages; ``None`` if none says."""
    try:
        import psutil
    except ImportError:
        pass
    else:
        return int(psutil.virtual_memory().available)
    try:
        with open("/proc/meminfo") as handle:
            for line in handle:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (AttributeError, ValueError, OSError):
        return None


#: What a refusal suggests by default.
ADVICE = "use a smaller graph, fewer env copies, a shorter n_steps or a smaller batch_size"


def check_memory(
    estimate: MemoryEstimate, what: str, available: int | None = None, advice: str = ADVICE
) -> None:
    """Refuse ``what`` (``training 4 agents on cycle``) when ``estimate`` exceeds the available
    memory, with one line giving both; warn on stderr past :data:`WARN_SHARE` of it.

    :param available: bytes (default :func:`available_memory`); ``None`` there: no check.
    :raises MemoryCheckError: naming the estimate, its largest parts and the limit.
    """
    available = available_memory() if available is None else available
    if available is None:
        return
    limit = format_bytes(available)
    if estimate.total > available:
        raise MemoryCheckError(
            f"{what} needs about {estimate.describe()}, more than the {limit} of memory available; {advice}"
        )
    if estimate.total > WARN_SHARE * available:
        print(
            f"warning: {what} needs about {estimate.describe()}, over half the {limit} of memory available",
            file=sys.stderr,
        )


__all__ = [
    "MemoryCheckError",
    "MemoryEstimate",
    "available_memory",
    "check_memory",
    "config_estimate",
    "dense_attention",
    "evaluation_estimate",
    "format_bytes",
    "graph_nodes",
    "training_estimate",
]
