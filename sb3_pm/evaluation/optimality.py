"""Every episode's optimality gap: the lower bound no team can beat, beside what the team scored.

:func:`episode_bound` computes :func:`sb3_pm.planning.lower_bound` from the env's state at reset
(the site, the start positions, the initial uncertainties, the horizon and the cap), cached per
episode, because a comparison evaluates many teams on the same episodes. The harness adds two
metrics to each record:

* ``lower_bound``: the bound on ``avg_uncertainty`` for that episode;
* ``x_lower_bound``: ``avg_uncertainty / lower_bound``, how many times the bound the team scored
  (NaN where the bound is 0, so that table means leave it out; the optimum itself may lie above
  the bound, docs/PLANNING.md).

Above :data:`PRICED_TARGETS_LIMIT` targets the per-episode bound is the step-by-step one alone:
the priced bound's programme grows with the targets (about 10 s an episode at 100 targets), and
``sb3-pm bound`` computes both wherever asked.
"""

from __future__ import annotations

from collections import OrderedDict
from typing import Any

import numpy as np

from sb3_pm.planning import lower_bound, stepwise_bound

__all__ = ["BOUND_METRICS", "PRICED_TARGETS_LIMIT", "add_gap", "episode_bound"]

#: Above this many targets an episode's record carries the step-by-step bound alone.
PRICED_TARGETS_LIMIT = 64

#: The metrics this module adds to an episode's record.
BOUND_METRICS = ("lower_bound", "x_lower_bound")
#: Episodes whose bound is kept: a sweep's evaluation episodes, several times over.
_CACHE_SIZE = 512
_cache: OrderedDict[tuple[Any, ...], float] = OrderedDict()


def episode_bound(state: Any) -> float:
    """The lower bound for the episode ``state`` (an env's ``unwrapped``) was just reset to."""
    graph = state.graph
    positions = np.asarray(state.positions, dtype=np.int64)
    initial = np.asarray(state.uncertainty, dtype=np.int64)
    key = (graph.fingerprint, positions.tobytes(), initial.tobytes(), int(state.max_cycles), int(state.u_max))
    if key in _cache:
        _cache.move_to_end(key)
        return _cache[key]
    horizon, cap = int(state.max_cycles), int(state.u_max)
    if graph.n_targets > PRICED_TARGETS_LIMIT:
        value = float(stepwise_bound(graph, positions, horizon, cap, initial).mean())
    else:
        value = lower_bound(graph, positions, horizon, cap, initial)
    _cache[key] = value
    if len(_cache) > _CACHE_SIZE:
        _cache.popitem(last=False)
    return value


def add_gap(metrics: dict[str, float], bound: float) -> dict[str, float]:
    """``metrics`` with :data:`BOUND_METRICS` added (a new dict)."""
    score = float(metrics["avg_uncertainty"])
    ratio = score / bound if bound > 0 else float("nan")
    return {**metrics, "lower_bound": float(bound), "x_lower_bound": ratio}
