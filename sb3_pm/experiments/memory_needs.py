"""A sweep's memory, checked before its folder is written: each cell's estimate
(:mod:`sb3_pm.zoo.memory`), and on the local backend the cells that run side by side together."""

from __future__ import annotations

from typing import Any

from sb3_pm.zoo import memory
from sb3_pm.zoo.memory import MemoryEstimate, config_estimate, evaluation_estimate, graph_nodes


def cell_estimate(cell: Any, graphs: dict[str, Any]) -> MemoryEstimate:
    """What one cell needs: training its team (a learned cell that trains here), else evaluating.

    :param graphs: resolved graphs and families by name, filled in as they are first needed.
    """
    from sb3_pm.experiments.runner import cell_config
    from sb3_pm.experiments.spec import Variant
    from sb3_pm.graphs import resolve_graph_or_family

    def graph(name: str) -> Any:
        if name not in graphs:
            graphs[name] = resolve_graph_or_family(name)
        return graphs[name]

    variant = Variant(**cell.variant)
    evaluation = evaluation_estimate(graph_nodes(graph(cell.graph)), cell.n_agents, learned=variant.learned)
    if not (variant.learned and variant.train):
        return evaluation
    config = cell_config(cell, variant)
    training = config_estimate(config, graph(variant.train_env or cell.graph))
    return max(training, evaluation, key=lambda estimate: estimate.total)


def check_sweep_memory(cells: list[Any], backend: str, n_jobs: int, what: str) -> None:
    """Refuse a sweep whose cells cannot fit: the largest one alone, and on the local backend the
    ``n_jobs`` largest together (they may run side by side, each process with its own copy of the
    graph). A Ray cluster's nodes are not this host: there only the largest cell is checked here.

    :raises sb3_pm.zoo.memory.MemoryCheckError: naming the estimate and the limit.
    """
    if not cells:
        return
    graphs: dict[str, Any] = {}
    estimates = sorted((cell_estimate(cell, graphs) for cell in cells), key=lambda e: e.total, reverse=True)
    side_by_side = 1 if backend != "local" else max(1, min(n_jobs, len(estimates)))
    available = memory.available_memory()
    if side_by_side == 1 or (available is not None and estimates[0].total > available):
        # one line: a cell too large alone is refused as such, whatever --jobs says
        memory.check_memory(estimates[0], f"{what}: its largest cell", available)
        return
    largest = estimates[:side_by_side]
    together = MemoryEstimate(tuple((f"cell {i + 1}", e.total) for i, e in enumerate(largest)))
    advice = "lower --jobs, or run the largest cells on their own (--graphs, --variants)"
    where = f"{what}: {side_by_side} cells side by side (--jobs {n_jobs})"
    memory.check_memory(together, where, available, advice=advice)


__all__ = ["cell_estimate", "check_sweep_memory"]
