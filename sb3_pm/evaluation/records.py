"""Saved evaluation records: reading ``--json`` files back, and the tail figures of a set of runs.

An evaluation record is what ``sb3-pm evaluate --json`` writes and what every sweep cell keeps as
``evaluation.json``: ``{"episodes": [...], "mean": {...}, "std": {...}, "config": {...}}``
(:meth:`~sb3_pm.evaluation.harness.EvaluationResult.to_dict`). Comparing two configurations after
the fact (``sb3-pm effect``) needs nothing else: the paired tests of
:func:`~sb3_pm.evaluation.statistics.effect` match episodes by their env seed.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sb3_pm.errors import InputError
from sb3_pm.evaluation.harness import EvaluationResult
from sb3_pm.evaluation.statistics import pooled_values


def load_record(path: Path | str) -> EvaluationResult:
    """One saved evaluation record, with a one-line error naming the file if it is not one."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"evaluation record {path} does not exist")
    try:
        payload = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise InputError(f"evaluation record {path} is not valid JSON ({error})") from None
    if (
        not isinstance(payload, dict)
        or not isinstance(payload.get("episodes"), list)
        or not payload["episodes"]
    ):
        raise InputError(f"{path} is not an evaluation record: no 'episodes' list (sb3-pm evaluate --json)")
    config = payload.get("config")
    if not isinstance(config, dict) or "graph" not in config or "policy" not in config:
        raise InputError(f"{path} is not an evaluation record: its 'config' names no graph and policy")
    try:
        return EvaluationResult.from_dict(payload)
    except (KeyError, TypeError, ValueError) as error:
        raise InputError(f"{path} is not an evaluation record: a malformed episode ({error!r})") from None


@dataclass(frozen=True)
class Tail:
    """The bad end of a set of runs' episodes on one graph.

    :ivar run_means: each run's mean of the metric, in the order given (one run = one record).
    :ivar p90: the 90th percentile of the metric over all episodes.
    :ivar max_neglect: mean ``max_neglect`` over the episodes (NaN if the records lack it).
    :ivar at_cap: episodes in which some target reached the cap ``u_max`` (``saturated_fraction > 0``).
    :ivar episodes: number of episodes.
    """

    run_means: tuple[float, ...]
    p90: float
    max_neglect: float
    at_cap: int
    episodes: int


def tail(results: Sequence[EvaluationResult], graph: str, metric: str) -> Tail:
    """:class:`Tail` of the runs of ``results`` on ``graph`` for ``metric``."""
    runs = [result for result in results if result.graph == graph and result.episodes]
    names = set(runs[0].metric_names)
    values = pooled_values(runs, metric)
    neglect = float(pooled_values(runs, "max_neglect").mean()) if "max_neglect" in names else float("nan")
    at_cap = (
        int(np.count_nonzero(pooled_values(runs, "saturated_fraction") > 0))
        if "saturated_fraction" in names
        else 0
    )
    return Tail(
        run_means=tuple(float(r.values(metric).mean()) for r in runs),
        p90=float(np.percentile(values, 90)),
        max_neglect=neglect,
        at_cap=at_cap,
        episodes=len(values),
    )


__all__ = ["Tail", "load_record", "tail"]
