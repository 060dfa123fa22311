"""The centralized plan: which agent patrols which targets (docs/PLANNING.md "Plans").

A plan gives every agent a group of targets, possibly leaving some targets to nobody; each agent
then follows :func:`~sb3_pm.planning.group_patrol.group_move` on its group with the true
uncertainties. Priced as if each agent were alone on its group (an agent crossing another's
target only lowers it), a plan's cost is a sum, so:

1. the groups start as the territory split (:func:`sb3_pm.graphs.territories.split_targets`),
   the convention ``territory_patrol`` keeps;
2. for given groups, the agents are matched to them by the Hungarian method
   (``scipy.optimize.linear_sum_assignment``) on each agent's solo cost from its own start;
3. local search moves a target to another group or to nobody, brings a dropped target back, or
   swaps two targets of two groups, taking the best improving change, until none improves. Where a
   round would price too many walks (:func:`~sb3_pm.planning.owned_search.exhaustive`), a search
   that tries nearby changes only and prices them with each group's own agent
   (:func:`~sb3_pm.planning.owned_search.descend_owned`) takes its place.

Every candidate is priced by simulation (:func:`~sb3_pm.planning.group_patrol.solo_cost`), cached
per (start, group). The plan is an upper bound on the optimum once replayed through the env.
"""

from __future__ import annotations

import multiprocessing
import os
import subprocess
import sys
import time
from dataclasses import dataclass, field
from functools import partial

import numpy as np

from sb3_pm.errors import InputError
from sb3_pm.graphs import GraphSpec
from sb3_pm.graphs.territories import split_targets
from sb3_pm.machine import usable_cores
from sb3_pm.planning.owned_search import descend_owned, exhaustive, nearest_targets
from sb3_pm.planning.pricer import GroupPricer
from sb3_pm.planning.target_tables import TargetTables

__all__ = ["PARALLEL_MIN_NODES", "PatrolPlan", "plan_both_ways", "plan_patrol", "uncertainty_at_reset"]

#: Sites of this many nodes or more run :func:`plan_both_ways`' two searches in two processes: a
#: search there takes seconds, well above the second process's start (about a second).
PARALLEL_MIN_NODES = 1000
#: The default wall-clock cap of the search, in seconds: a plan for one episode.
DEFAULT_SEARCH_SECONDS = 60.0
#: The default number of perturbed restarts of the local search.
DEFAULT_RESTARTS = 20


@dataclass(frozen=True)
class PatrolPlan:
    """Each agent's group of targets.

    :ivar groups: one tuple of target nodes per agent, in agent order (empty: the agent idles), in
        the order its rule reads them.
    :ivar rules: each agent's group rule (:data:`~sb3_pm.planning.group_patrol.RULES`).
    :ivar dropped: the targets no agent patrols.
    :ivar predicted: the plan's decomposed ``avg_uncertainty`` (each agent alone on its group).
    :ivar searched: local-search rounds taken; ``complete`` is False if the time budget ran out.
    """

    groups: tuple[tuple[int, ...], ...]
    rules: tuple[str, ...]
    dropped: tuple[int, ...]
    predicted: float
    searched: int = 0
    complete: bool = True
    notes: dict[str, float] = field(default_factory=dict)


def _neighbours(groups: list[tuple[int, ...]], dropped: tuple[int, ...]):
    """Every plan one change away: a move, a drop, a return or a swap."""
    n = len(groups)
    for g, group in enumerate(groups):
        for target in group:
            rest = tuple(t for t in group if t != target)
            for h in range(n):
                if h != g:
                    moved = list(groups)
                    moved[g], moved[h] = rest, tuple(sorted(groups[h] + (target,)))
                    yield moved, dropped
            yield (
                [rest if i == g else grp for i, grp in enumerate(groups)],
                tuple(sorted(dropped + (target,))),
            )
    for target in dropped:
        rest_dropped = tuple(t for t in dropped if t != target)
        for h in range(n):
            moved = list(groups)
            moved[h] = tuple(sorted(groups[h] + (target,)))
            yield moved, rest_dropped
    for g in range(n):
        for h in range(g + 1, n):
            for a in groups[g]:
                for b in groups[h]:
                    moved = list(groups)
                    moved[g] = tuple(sorted(t for t in groups[g] if t != a) + [b])
                    moved[h] = tuple(sorted(t for t in groups[h] if t != b) + [a])
                    yield moved, dropped


def _descend(
    pricer: GroupPricer, groups: list[tuple[int, ...]], dropped: tuple[int, ...], deadline: float
) -> tuple[int, list[tuple[int, ...]], tuple[int, ...], list[int], int, bool]:
    """Best-improvement local search from ``groups``: (cost, groups, dropped, order, rounds, complete)."""
    best, order = pricer.total(groups, dropped)
    rounds = 0
    while True:
        improved = None
        candidates = list(_neighbours(groups, dropped))
        pricer.prefetch({group for candidate, _ in candidates for group in candidate})
        for candidate, candidate_dropped in candidates:
            if time.monotonic() > deadline:
                if improved is not None:
                    groups, dropped, order = improved[1:]
                    best = improved[0]
                return best, groups, dropped, order, rounds, False
            cost, candidate_order = pricer.total(candidate, candidate_dropped)
            if cost < best and (improved is None or cost < improved[0]):
                improved = (cost, candidate, candidate_dropped, candidate_order)
        if improved is None:
            return best, groups, dropped, order, rounds, True
        best, groups, dropped, order = improved
        rounds += 1


def _perturbed(
    groups: list[tuple[int, ...]], dropped: tuple[int, ...], rng: np.random.Generator, moves: int
) -> tuple[list[tuple[int, ...]], tuple[int, ...]]:
    """``groups`` with ``moves`` random targets moved to random groups (dropped ones come back)."""
    groups = [list(group) for group in groups]
    pool = list(dropped)
    for _ in range(moves):
        filled = [g for g, group in enumerate(groups) if group]
        if not filled:
            break
        source = groups[int(rng.choice(filled))]
        pool.append(source.pop(int(rng.integers(len(source)))))
    for target in pool:
        groups[int(rng.integers(len(groups)))].append(target)
    return [tuple(sorted(group)) for group in groups], ()


def uncertainty_at_reset(graph: GraphSpec, initial_uncertainty: np.ndarray | None) -> np.ndarray:
    """``(N,)`` the nodes' ``u`` at reset that a plan starts from: ``initial_uncertainty`` as given,
    or zeros (the environment's default) where it is ``None``."""
    if initial_uncertainty is None:
        return np.zeros(graph.n_nodes, dtype=np.int64)
    return np.asarray(initial_uncertainty)


def plan_patrol(
    graph: GraphSpec,
    starts: np.ndarray,
    max_cycles: int,
    u_max: int,
    initial_uncertainty: np.ndarray | None = None,
    search_seconds: float = DEFAULT_SEARCH_SECONDS,
    restarts: int = DEFAULT_RESTARTS,
    tour_groups: bool = True,
) -> PatrolPlan:
    """The best plan the search finds for one episode.

    Local search from the territory split, then ``restarts`` times from the best plan so far with
    a few targets moved at random (iterated local search; the random stream is seeded, so the plan
    depends only on the arguments unless the time budget runs out first).

    :param graph: the site.
    :param starts: ``(n,)`` the agents' start nodes.
    :param max_cycles: ``K``, the episode's length.
    :param u_max: the uncertainty cap.
    :param initial_uncertainty: ``(N,)`` the uncertainties at reset (default: all 0).
    :param search_seconds: a wall-clock cap on the search (``complete`` is False where it cut it).
    :param restarts: perturbed restarts after the first local optimum.
    :param tour_groups: also price each group of 3 or more targets by the ``tour`` rule, and keep
        the cheaper rule per agent; False plans with the ``stalest`` rule alone, for a team that
        plays nothing else (the planned territory convention, :mod:`sb3_pm.planning.conventions`).
    """
    starts = np.asarray(starts, dtype=np.int64)
    if starts.ndim != 1 or starts.size == 0:
        raise InputError(f"starts must be a non-empty list of nodes, got {starts.tolist()}")
    if search_seconds <= 0:
        raise InputError(f"search_seconds must be positive, got {search_seconds}")
    if restarts < 0:
        raise InputError(f"restarts must be >= 0, got {restarts}")
    initial = uncertainty_at_reset(graph, initial_uncertainty)
    tables = TargetTables(graph)
    pricer = GroupPricer(tables, tables.labels(starts), initial, max_cycles, u_max, tour_groups)
    n = starts.size
    owner = split_targets(tables.between, np.arange(tables.between.shape[0]), n)
    groups = [tuple(int(t) for t in np.flatnonzero(owner == i)) for i in range(n)]
    deadline = time.monotonic() + search_seconds
    pricer.prefetch(set(groups))
    first, _ = pricer.total(groups, ())
    if not exhaustive(n, tables.between.shape[0]):
        descend = partial(descend_owned, pricer, deadline=deadline, near=nearest_targets(tables.between))
    else:
        descend = partial(_descend, pricer, deadline=deadline)
    best, groups, dropped, order, rounds, complete = descend(groups, ())
    rng = np.random.default_rng(0)
    for _ in range(restarts):
        if not complete:
            break
        moves = int(rng.integers(1, 4))
        start_groups, start_dropped = _perturbed(groups, dropped, rng, moves)
        cost, found, found_dropped, found_order, more, complete = descend(start_groups, start_dropped)
        rounds += more
        if cost < best:
            best, groups, dropped, order = cost, found, found_dropped, found_order
    chosen = [pricer.rule[(pricer.starts[agent], groups[order[agent]])] for agent in range(n)]
    return PatrolPlan(
        groups=tuple(tables.nodes(ordered) for _, ordered in chosen),
        rules=tuple(rule for rule, _ in chosen),
        dropped=tables.nodes(dropped),
        predicted=best / max_cycles,
        searched=rounds,
        complete=complete,
        notes={"territory_split": first / max_cycles},
    )


def plan_both_ways(
    graph: GraphSpec,
    starts: np.ndarray,
    max_cycles: int,
    u_max: int,
    initial_uncertainty: np.ndarray | None = None,
    search_seconds: float = DEFAULT_SEARCH_SECONDS,
    restarts: int = DEFAULT_RESTARTS,
) -> PatrolPlan:
    """The lower of two :func:`plan_patrol` searches, each with ``search_seconds`` and ``restarts``:
    free to walk groups as tours, and by the ``stalest`` rule alone. The two land in other local
    optima, and the one free to take tours is not always lower; on a tie it is kept.

    On sites of :data:`PARALLEL_MIN_NODES` nodes or more, where a second core is free, the search
    free to take tours runs in a process of its own beside the other (the same plans either way).
    """
    arguments = {
        "starts": starts,
        "max_cycles": max_cycles,
        "u_max": u_max,
        "initial_uncertainty": initial_uncertainty,
        "search_seconds": search_seconds,
        "restarts": restarts,
    }
    if graph.n_nodes >= PARALLEL_MIN_NODES and _second_core_free():
        worker = _start_search(graph, {**arguments, "tour_groups": True})
        try:
            stalest = plan_patrol(graph, **arguments, tour_groups=False)
            searches = [_plan_of(worker), stalest]
        finally:
            if worker.poll() is None:  # this search failed or was interrupted: stop the other
                worker.kill()
                worker.wait()
    else:
        searches = [plan_patrol(graph, **arguments, tour_groups=tours) for tours in (True, False)]
    return min(searches, key=lambda searched: searched.predicted)


def _start_search(graph: GraphSpec, arguments: dict) -> subprocess.Popen:
    """Start :func:`plan_patrol` on ``graph`` with keyword ``arguments`` in a worker process of its
    own (:mod:`sb3_pm.planning.search_worker`, one torch thread)."""
    from sb3_pm.planning.search_worker import request

    worker = subprocess.Popen(
        [sys.executable, "-m", "sb3_pm.planning.search_worker"],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        env={**os.environ, "OMP_NUM_THREADS": "1"},
    )
    assert worker.stdin is not None
    worker.stdin.write(request(graph, arguments))
    worker.stdin.close()
    return worker


def _plan_of(worker: subprocess.Popen) -> PatrolPlan:
    """The plan :func:`_start_search`'s worker found, once it is done.

    :raises RuntimeError: if the worker failed (its error is on standard error).
    """
    from sb3_pm.planning.search_worker import plan_from

    assert worker.stdout is not None
    output = worker.stdout.read()
    if worker.wait() != 0:
        raise RuntimeError(f"the plan search's worker process failed (exit status {worker.returncode})")
    return plan_from(output)


def _second_core_free() -> bool:
    """Whether this process may start a worker on a second core: it has two cores or more, and it
    is not a daemon (a vectorized env's worker, whose siblings share the cores already)."""
    return usable_cores() >= 2 and not multiprocessing.current_process().daemon
