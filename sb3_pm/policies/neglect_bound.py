"""The neglect bound: a deadline filter that keeps every known target's uncertainty below a bound.

The paper's barrier (rules 2-4 of :mod:`sb3_pm.policies.dcbf`) constrains the agent on every step,
so little is left to learn. This filter constrains it only when it must. Each agent keeps, from its
own mental map alone, a worst-case projection of every target it knows:

    ``ū_m = min(u_max, u_m + age_m)``

(``u_m`` last observed, ``age_m`` steps ago). It is a true upper bound on the target's uncertainty
now, whatever the teammates did, because eq. (1) raises ``u`` by at most 1 per step. With ``d_m`` the
hop distance from the agent to ``m`` over the agent's *known* edges, ``ū_m + d_m`` bounds the
target's uncertainty when the agent could be there by going straight now. The target is *due*
when

    ``ū_m + d_m >= B - 1``

(``B`` = ``neglect_bound``): one more free step (``ū`` and ``d`` each grow by at most 1) could put
the arrival bound above ``B``. Then the allowed set becomes the next hops along shortest known
paths to the nearest due target (ties: the least slack ``B - ū_m - d_m``, then the lower node
index), or ``{φ}`` when the agent stands on it. It overrides the
freeze and the paper's barrier; collision avoidance may still drop one of several next hops but
never empties the set. Targets it does not know and targets it cannot reach over known edges are
never due.

**Guarantee** (``tests/test_neglect_bound.py``). Assumptions: a static graph, the agent's own map
(no teammate knowledge), and a target ``m`` that the agent knows at some step with
``ū_m + d_m <= B``. Then, as long as no other target of the agent is due while ``m`` is due,
the true uncertainty of ``m`` never exceeds ``B``:

* while ``m`` is not due, ``ū_m <= B - 2 - d_m <= B``;
* while it is due, every step moves one hop closer (known edges are real edges), so
  ``ū_m + d_m`` does not grow and the agent arrives with ``u_m <= ū_m <= B``, then stays while
  ``u_m >= B - 1``.

So an agent with one known target, or whose targets are never due at the same time, keeps each of
them at or below ``B``; any teammate's visit only lowers ``u``. When two targets are due together,
one of them can exceed ``B``: one agent cannot be in two places, and without communication no agent
knows whether a teammate is already on the way. The filter uses the worst-case projection, not the
estimator's ``û``: a learned prediction could make the filter late, which would void the guarantee.
"""

from __future__ import annotations

import torch as th

from sb3_pm.policies.features import hop_distances as breadth_first_hops

#: Distance of a node not reachable over the known edges.
UNREACHABLE = 1 << 30


def hop_distances(adjacency: th.Tensor, sources: th.Tensor) -> th.Tensor:
    """Breadth-first hop distances from one source node per graph (``features.hop_distances``),
    with :data:`UNREACHABLE` where no path exists.

    Shapes:
        - adjacency: ``(B, N, N)`` any dtype (``!= 0`` is an edge); sources: ``(B,)`` long
        - output: ``(B, N)`` long
    """
    start = th.nn.functional.one_hot(sources.long(), adjacency.shape[-1])
    distance = breadth_first_hops(adjacency, start)
    return th.where(distance < 0, UNREACHABLE, distance)


#: The known edges of a batch of edges-layout maps: ``edge_index`` ``(B, 2, E)`` and ``edge_mask``
#: ``(B, E)`` (:mod:`sb3_pm.policies.edges`), read in place of a dense ``(B, N, N)`` adjacency.
EdgeMaps = tuple[th.Tensor, th.Tensor]


def edge_hop_distances(edges: EdgeMaps, rows: th.Tensor, sources: th.Tensor, n_nodes: int) -> th.Tensor:
    """:func:`hop_distances` over the known edges of maps ``rows`` of an edges-layout batch: one
    breadth-first search per map (scipy's, on the CPU), ``O(N + E)`` each, where the dense search
    costs ``O(N^2)`` per hop. Maps with the same known edges (all of them, with a known road
    network) share one sparse matrix and one call.

    Shapes:
        - edges: ``(B, 2, E)``, ``(B, E)``; rows, sources: ``(b,)`` long
        - output: ``(b, N)`` long, :data:`UNREACHABLE` where no path exists
    """
    import numpy as np
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import shortest_path

    edge_index, edge_mask = edges
    known = (edge_mask[rows] != 0).cpu().numpy()  # (b, E)
    index = edge_index[rows].long().cpu().numpy()  # (b, 2, E)
    starts = sources.long().cpu().numpy()
    result = np.empty((len(starts), n_nodes), dtype=np.int64)
    done = np.zeros(len(starts), dtype=bool)
    for first in range(len(starts)):
        if done[first]:
            continue
        same = ~done & (known == known[first]).all(axis=1) & (index == index[first]).all(axis=(1, 2))
        keep = known[first]
        i, j = index[first, 0, keep], index[first, 1, keep]
        # edge [i, j] is a step from i to j, as the dense search's frontier-times-adjacency takes it
        matrix = csr_matrix((np.ones(i.size, dtype=np.int8), (i, j)), shape=(n_nodes, n_nodes))
        hops = shortest_path(matrix, directed=True, unweighted=True, indices=starts[same])
        result[same] = np.where(np.isinf(hops), UNREACHABLE, hops).astype(np.int64)
        done |= same
    return th.as_tensor(result, device=sources.device)


def _distances(graph: th.Tensor | EdgeMaps, rows: th.Tensor, sources: th.Tensor, n_nodes: int) -> th.Tensor:
    """``(b, N)`` hops from ``sources`` on maps ``rows``: a dense adjacency or an edges-layout batch."""
    if isinstance(graph, tuple):
        return edge_hop_distances(graph, rows, sources, n_nodes)
    return hop_distances(graph[rows], sources)


def neglect_deadline(
    u_last: th.Tensor,
    age: th.Tensor,
    known_target: th.Tensor,
    adjacency: th.Tensor | EdgeMaps,
    position: th.Tensor,
    reachable: th.Tensor,
    bound: float,
    u_max: float,
) -> tuple[th.Tensor, th.Tensor]:
    """Which maps have a due target, and the next hops towards the most urgent one.

    :param u_last: last observed uncertainty per node (the map's ``u``).
    :param age: steps since each node was last observed.
    :param known_target: the map's target flags (bool).
    :param adjacency: the known adjacency ``(B, N, N)``, or an edges-layout batch's known edges
        (:data:`EdgeMaps`: searched without building the adjacency).
    :param position: the agent's node ``φ``.
    :param reachable: the reachable set ``R`` (bool).
    :param bound: ``B``, in units of ``u``.
    :param u_max: the cap of ``u`` (the projection never exceeds it).
    :return: ``forced`` ``(B,)`` bool (a target is due) and ``allowed`` ``(B, N)`` bool (the next
        hops towards it, within ``R``; meaningful only where ``forced``).

    Shapes:
        - u_last, age, known_target, reachable: ``(B, N)``; adjacency: ``(B, N, N)``
        - position: ``(B,)`` long
    """
    batch, n = u_last.shape
    projected = th.clamp(u_last + age, max=u_max)  # ū: a true upper bound on u now
    known = known_target.bool()
    forced = th.zeros(batch, dtype=th.bool, device=u_last.device)
    allowed = th.zeros((batch, n), dtype=th.bool, device=u_last.device)
    # A target can be due only if ū_m + (N - 1) >= B - 1 (no known path is longer); maps with no
    # such target skip both searches (early in an episode; later most maps pass this test).
    candidates = (known & (projected + (n - 1) >= bound - 1)).any(-1)
    if not bool(candidates.any()):
        return forced, allowed
    rows = candidates.nonzero().squeeze(-1)
    distance = _distances(adjacency, rows, position[rows], n)  # (b, N) from the agent
    reachable_target = known[rows] & (distance < UNREACHABLE)
    arrival = projected[rows] + distance.to(projected.dtype)  # bound on u at arrival
    due = reachable_target & (arrival >= bound - 1)
    due_rows = due.any(-1)
    if not bool(due_rows.any()):
        return forced, allowed
    # Nearest due target first (ties: the least slack B - arrival, then the lower node index, as
    # argmax returns the first maximum). Not earliest-deadline-first: while the agent walks to one
    # due target, every other one's arrival bound grows, so EDF would turn it round and round
    # between two targets; with nearest-first, the distance to the nearest due target falls by
    # one hop per step, so the agent reaches a due target within its distance.
    nearest = distance.masked_fill(~due, UNREACHABLE).amin(-1, keepdim=True)
    key = th.where(due & (distance == nearest), arrival, th.full_like(arrival, -float("inf")))
    chosen = key.argmax(-1)  # (b,)
    rows, chosen = rows[due_rows], chosen[due_rows]
    # Hop distances from the chosen target give, for each neighbour, whether it is one hop closer.
    from_target = _distances(adjacency, rows, chosen, n)
    here = position[rows]
    picked = th.arange(len(rows), device=u_last.device)
    own_distance = from_target[picked, here]  # (k,), the agent's distance to its target
    closer = from_target == (own_distance - 1).unsqueeze(-1)
    at_target = own_distance == 0
    step = th.where(
        at_target.unsqueeze(-1), th.nn.functional.one_hot(here, n).bool(), closer & reachable[rows].bool()
    )
    forced[rows] = step.any(-1)  # always true on a known, reachable target; kept as a guard
    allowed[rows] = step
    return forced, allowed


__all__ = ["UNREACHABLE", "EdgeMaps", "edge_hop_distances", "hop_distances", "neglect_deadline"]
