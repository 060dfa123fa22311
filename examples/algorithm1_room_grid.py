"""Build a graph with the paper's Algorithm 1 (a 2-D room cut into cells) and compare baselines on it.

What it shows:

* :func:`sb3_pm.graphs.hyperrectangle`: a ``lengths`` box cut into ``chunk_sizes`` cells; cells
  that touch (faces or corners) are joined, so a 2-D room becomes an 8-neighbour grid graph;
* saving it as GraphML so that every tool can name it by path;
* :func:`sb3_pm.evaluation.compare` over the non-learning baselines (random, local_greedy,
  grazing, tour_patrol ...), and :meth:`Comparison.write`: ``table.md``, ``table.csv``,
  ``table.tex``, ``anova.txt``, ``results.json``, ``uncertainty.png`` and ``table.png``.

Command-line equivalent:
``sb3-pm compare --policies random local_greedy --graphs room.graphml --out runs/room_cli``.

Usage::

    python examples/algorithm1_room_grid.py --out runs/room
    SB3_PM_SMOKE=1 python examples/algorithm1_room_grid.py
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

from sb3_pm.baselines import BASELINES, make_team
from sb3_pm.evaluation import compare, markdown_table
from sb3_pm.graphs import hyperrectangle, save_graphml


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--length", type=float, nargs=2, default=[8.0, 6.0], help="room size (x, y)")
    parser.add_argument("--cell", type=float, nargs=2, default=[1.0, 1.0], help="cell size (x, y)")
    parser.add_argument("--targets", type=int, default=6)
    parser.add_argument("--episodes", type=int, default=5)
    parser.add_argument("--out", default=None, help="output folder (default: a new temp dir)")
    parser.add_argument("--smoke", action="store_true", help="tiny budget (also: SB3_PM_SMOKE=1)")
    args = parser.parse_args()
    smoke = args.smoke or os.environ.get("SB3_PM_SMOKE") == "1"
    out = Path(args.out or tempfile.mkdtemp(prefix="sb3_pm_room_"))
    out.mkdir(parents=True, exist_ok=True)

    # Algorithm 1: an 8 x 6 room with 1 x 1 cells -> 48 nodes, 8-neighbour adjacency.
    room = hyperrectangle(args.length, args.cell, n_targets=args.targets, seed=0, name="room")
    path = save_graphml(room, out / "room.graphml", overwrite=True)
    print(f"Algorithm 1 graph: {room.n_nodes} cells, {int(room.adjacency.sum()) // 2} edges -> {path}")

    episodes, max_cycles = args.episodes, 500
    if smoke:
        episodes, max_cycles = 1, 40
    teams = {name: (lambda graph, name=name: make_team(name)) for name in BASELINES}
    comparison = compare(teams, [str(path)], seeds=[0], episodes=episodes, n_agents=3, max_cycles=max_cycles)
    written = comparison.write(out / "report")
    print(markdown_table(comparison.table))
    print("wrote", ", ".join(p.name for p in written), "to", out / "report")


if __name__ == "__main__":
    main()
