"""Lower bounds on any team's ``avg_uncertainty`` (docs/PLANNING.md "Lower bounds").

Two relaxations of the dynamics, both keeping the travel rule and the start positions; the bound
is the larger. Proofs are sketched in docs/PLANNING.md and checked against exhaustive search on
small graphs in ``tests/test_planning.py``.

* **Step by step** (:func:`stepwise_bound`). Below the cap, eq. (1) changes the summed target
  uncertainty by ``S_k - S_{k-1} = T - o_k - o+_k - c_k``: ``o_k`` distinct targets occupied after
  move ``k``, ``o+_k`` of them with ``u > 0``, ``c_k`` empty targets already at the cap. With
  ``m_k`` the most targets the agents can stand on after ``k`` moves from their starts, ``o_k <=
  m_k``, ``o+_k <= min(m_k, S_{k-1})``, and ``c_k`` is at most ``floor(S_{k-1} / u_max)`` and at
  most the targets that could have grown to the cap by then.
* **Target by target** (:func:`priced_bound`). Each target's summed ``u`` depends only on when it
  is occupied. Every occupied target-step takes an agent-step, and every arrival takes the
  agent's steps off targets since it left its last one: at least the hops to the nearest other
  target, less one.
  Pricing agent-steps at ``λ >= 0`` separates the targets; each one's best schedule is a small
  dynamic programme, and the best price is found by a concave search.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

from sb3_pm.errors import InputError
from sb3_pm.graphs import GraphSpec

__all__ = ["coverable_targets", "lower_bound", "priced_bound", "stepwise_bound"]

#: The price search: rounds of a grid, each zoomed in on the last one's best price.
_PRICE_ROUNDS = 4
_PRICE_GRID = 12


def _integers(values: object, what: str) -> np.ndarray:
    """``values`` as int64, refusing non-integral numbers rather than truncating them."""
    array = np.asarray(values)
    if array.dtype.kind not in "iu" and not (array.dtype.kind == "f" and np.all(array == np.round(array))):
        raise InputError(f"{what} must be integers, got {array.tolist()}")
    return array.astype(np.int64)


def checked_starts(graph: GraphSpec, starts: np.ndarray, max_cycles: int, u_max: int) -> np.ndarray:
    """``starts`` as ``(n,)`` int64 nodes, refusing what no episode can start from (one line)."""
    starts = _integers(starts, "starts")
    if starts.ndim != 1 or starts.size == 0:
        raise InputError(f"starts must be a non-empty list of nodes, got {starts.tolist()}")
    if ((starts < 0) | (starts >= graph.n_nodes)).any():
        raise InputError(f"starts {starts.tolist()} are not all nodes of 0..{graph.n_nodes - 1}")
    if max_cycles < 1 or u_max < 1:
        raise InputError(f"max_cycles and u_max must be positive, got {max_cycles} and {u_max}")
    return starts


def initial_targets(graph: GraphSpec, initial_uncertainty: np.ndarray | None, u_max: int) -> np.ndarray:
    """``(T,)`` the targets' uncertainties at reset (zeros by default), checked to be ``N``
    integers in ``[0, u_max]``."""
    if initial_uncertainty is None:
        return np.zeros(graph.n_targets, dtype=np.int64)
    values = _integers(initial_uncertainty, "initial_uncertainty")
    if values.shape != (graph.n_nodes,) or (values < 0).any() or (values > u_max).any():
        raise InputError(f"initial_uncertainty must be {graph.n_nodes} integers in [0, {u_max}]")
    return values[graph.target_indices]


def coverable_targets(
    hop_distances: np.ndarray, target_indices: np.ndarray, starts: np.ndarray
) -> np.ndarray:
    """``m_k``, the most distinct targets the agents can occupy after ``k`` moves.

    :param hop_distances: ``(N, N)`` hop distances.
    :param target_indices: ``(T,)`` the target nodes.
    :param starts: ``(n,)`` the agents' start nodes.
    :return: ``(D + 1,)`` int, entry ``k`` for ``k = 0 .. D`` (a maximum matching of agents to the
        targets at most ``k`` hops away); entry ``D`` holds for every ``k >= D``.
    """
    distances = np.asarray(hop_distances)[np.ix_(np.asarray(starts), np.asarray(target_indices))]  # (n, T)
    return coverable_from(distances)


def coverable_from(distances: np.ndarray) -> np.ndarray:
    """:func:`coverable_targets` from the ``(n, T)`` hop distances of the starts to the targets."""
    if distances.size == 0:
        return np.zeros(1, dtype=np.int64)
    counts = np.empty(int(distances.max()) + 1, dtype=np.int64)
    for k in range(counts.size):
        reachable = distances <= k  # (n, T)
        # A maximum matching as a min-cost assignment: a reachable pair costs -1, any other 0.
        rows, cols = linear_sum_assignment(-reachable.astype(np.float64))
        counts[k] = int(reachable[rows, cols].sum())
    return counts


def stepwise_bound(
    graph: GraphSpec,
    starts: np.ndarray,
    max_cycles: int,
    u_max: int,
    initial_uncertainty: np.ndarray | None = None,
) -> np.ndarray:
    """``L_k`` for every step ``k``: no team's summed target uncertainty after step ``k`` is lower.

    ``L_k = max(0, min over S >= L_{k-1} of f_k(S))`` with ``f_k(S) = S + T - m_k - min(m_k, S)
    - min(floor(S / u_max), C_k)``, where ``C_k`` counts the targets that could be at the cap before
    step ``k`` (``u_0 + k - 1 >= u_max``). Since the true ``S_k >= f_k(S_{k-1})`` and ``S_{k-1} >=
    L_{k-1}``, induction gives ``S_k >= L_k``.

    :param graph: the site.
    :param starts: ``(n,)`` the agents' start nodes.
    :param max_cycles: ``K``, the episode's length in steps.
    :param u_max: the uncertainty cap.
    :param initial_uncertainty: ``(N,)`` the uncertainties at reset (default: all 0).
    :return: ``(K,)`` int64.
    """
    starts = checked_starts(graph, starts, max_cycles, u_max)
    initial = initial_targets(graph, initial_uncertainty, u_max)
    n_targets = int(initial.size)
    coverable = coverable_from(graph.routes.to_targets(starts))  # no all-pairs table on a large site
    # Before step k a target's u is at most u_0 + k - 1, so few can be at the cap early on.
    first_capped = np.sort(np.maximum(u_max - initial, 0) + 1)  # (T,) the earliest step each may be

    def step(total: int, m: int, capped: int) -> int:
        return total + n_targets - m - min(m, total) - min(total // u_max, capped)

    total = int(initial.sum())
    bounds = np.empty(max_cycles, dtype=np.int64)
    for k in range(1, max_cycles + 1):
        m = int(coverable[min(k, coverable.size - 1)])
        capped = int(np.searchsorted(first_capped, k, side="right"))
        # Below m, f_k is T - m less the cap term, which may fall as S grows; from m on it never
        # falls. So its least value over S >= L_{k-1} is at L_{k-1}, m - 1 or m.
        candidates = [total] + ([m - 1, m] if total < m else [])
        total = max(0, min(step(s, m, capped) for s in candidates))
        bounds[k - 1] = total
    return bounds


def _priced_targets(
    prices: np.ndarray,
    max_cycles: int,
    u_max: int,
    initial: np.ndarray,
    earliest: np.ndarray,
    starts_on: np.ndarray,
    walk: np.ndarray,
    first_walk: np.ndarray,
) -> np.ndarray:
    """Each target's least ``summed u + price × agent-steps``, the target alone, at each price.

    A dynamic programme over ``(price, target, occupied before, visited before, u)``, all prices and
    targets at once.

    :param prices: ``(P,)`` prices of an agent-step.
    :param initial: ``(T,)`` u at reset; :param earliest: ``(T,)`` the first step each can be
        occupied; :param starts_on: ``(T,)`` an agent starts on it; :param walk: ``(T,)`` the
        off-target agent-steps an arrival takes; :param first_walk: ``(T,)`` those of the first one.
    :return: ``(P, T)``.
    """
    levels = np.arange(u_max + 1)
    grow, clear = np.minimum(levels + 1, u_max), np.maximum(levels - 1, 0)  # (U+1,)
    n_targets = initial.size
    price = np.asarray(prices, dtype=np.float64)[:, None, None, None]  # (P, 1, 1, 1)
    # value[q, i, p, v, u]: least cost of the remaining steps of target i at price q, occupied at
    # the step before (p), ever occupied (v), at u.
    value = np.zeros((price.shape[0], n_targets, 2, 2, u_max + 1))
    walks = np.stack([first_walk, walk], axis=1)[None, :, :, None]  # (1, T, v, 1)
    arrive = price * (1.0 + walks)  # (P, T, v, 1)
    for k in range(max_cycles, 0, -1):
        allowed = (k >= earliest)[None, :, None, None]  # (1, T, 1, 1)
        empty = grow + value[:, :, 0][..., grow]  # (P, T, v, U+1)
        then = value[:, :, 1, 1][:, :, None, clear]  # (P, T, 1, U+1): v is 1 once occupied
        stay = clear + price + then
        enter = clear + arrive + then
        occupied_before = np.where(allowed, np.minimum(empty, stay), empty)
        empty_before = np.where(allowed, np.minimum(empty, enter), empty)
        value = np.stack([empty_before, occupied_before], axis=2)
    index = starts_on.astype(np.int64)
    return value[:, np.arange(n_targets), index, index, initial]


def priced_bound(
    graph: GraphSpec,
    starts: np.ndarray,
    max_cycles: int,
    u_max: int,
    initial_uncertainty: np.ndarray | None = None,
) -> float:
    """The target-by-target bound on ``avg_uncertainty`` (arguments as :func:`stepwise_bound`).

    For any team, with ``A`` the agent-steps its occupancies and arrival walks take (at most
    ``n (K + 1)``, one per agent and time ``0`` to ``K``), ``Σ_i cost_i >= Σ_i min (cost_i + λ A_i)
    - λ n (K + 1)`` for every price ``λ >= 0``; the bound is the best such price's value. An
    arrival at target ``i`` is charged ``d_i - 1`` walk steps (``d_i``: hops to the nearest other
    target), the first one ``min(d_i - 1, hops from an off-target start)``. Where a real walk is
    shorter (an agent returning to ``i``, or a fresh agent arriving where another has been), it
    spans the whole gap since ``i`` was last occupied, and holding ``i`` through that gap is an
    allowed schedule that costs no more (docs/PLANNING.md, "Lower bounds").
    """
    starts = checked_starts(graph, starts, max_cycles, u_max)
    targets = graph.target_indices
    if targets.size == 0:
        return 0.0
    initial = initial_targets(graph, initial_uncertainty, u_max)
    distances = graph.routes.to_targets(starts)  # (n, T)
    earliest = distances.min(axis=0)
    starts_on = earliest == 0
    earliest = np.maximum(earliest, 1)
    between = graph.routes.between_targets().astype(np.float64)  # (T, T)
    np.fill_diagonal(between, np.inf)
    walk = np.minimum(between.min(axis=1) - 1, max_cycles)  # (T,) inf (one target) -> K
    off_target = ~graph.targets.astype(bool)[starts]
    first_walk = walk.copy()
    if off_target.any():
        first_walk = np.minimum(walk, distances[off_target].min(axis=0))
    capacity = starts.size * (max_cycles + 1)
    # Targets alike in everything the programme reads share one solution: solve each kind once.
    kinds, counts = np.unique(
        np.stack([initial, earliest, starts_on, walk, first_walk], axis=1).astype(np.int64),
        axis=0,
        return_counts=True,
    )
    initial, earliest, walk, first_walk = kinds[:, 0], kinds[:, 1], kinds[:, 3], kinds[:, 4]
    starts_on = kinds[:, 2].astype(bool)

    def dual(prices: np.ndarray) -> np.ndarray:
        per_kind = _priced_targets(prices, max_cycles, u_max, initial, earliest, starts_on, walk, first_walk)
        return per_kind @ counts - prices * capacity

    # The dual is concave in the price; an agent-step is worth at most 2 u per remaining step, so
    # its best price lies in [0, 2 K]. Zoom a grid in on the best price.
    low, high = 0.0, 2.0 * max_cycles
    best = -np.inf
    for _ in range(_PRICE_ROUNDS):
        prices = np.linspace(low, high, _PRICE_GRID)
        values = dual(prices)
        pick = int(np.argmax(values))
        best = max(best, float(values[pick]))
        step = prices[1] - prices[0]
        low, high = max(0.0, prices[pick] - step), prices[pick] + step
    return best / max_cycles


def lower_bound(
    graph: GraphSpec,
    starts: np.ndarray,
    max_cycles: int,
    u_max: int,
    initial_uncertainty: np.ndarray | None = None,
) -> float:
    """The library's lower bound on ``avg_uncertainty`` for any team: the larger of
    :func:`stepwise_bound` (averaged over the steps) and :func:`priced_bound`."""
    stepwise = float(stepwise_bound(graph, starts, max_cycles, u_max, initial_uncertainty).mean())
    return max(stepwise, priced_bound(graph, starts, max_cycles, u_max, initial_uncertainty))
