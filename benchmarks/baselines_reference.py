"""Our baselines next to the reference figures of ``shared/graphs/README.md``.

Usage::

    python benchmarks/baselines_reference.py ../shared/graphs [--seeds 3] [--episodes 5] [--steps 500]

Protocol as the reference: 4 agents, 3 seeds x 5 episodes x 500 steps, random distinct starts.
Seed ``s`` evaluates env seeds ``s * 1000 + e`` (the ``sb3-pm compare`` convention).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from sb3_pm.baselines import BASELINES, make_team
from sb3_pm.evaluation import SEED_STRIDE, evaluate, pooled_values

#: (graph stem, policy) -> (avg_uncertainty, max_neglect) from the README's table.
REFERENCE = {
    ("paper_50n_8t", "random"): (704.8, 110.7),
    ("paper_50n_8t", "sit_on_nodes"): (360.4, 500.0),
    ("paper_50n_8t", "grazing"): (116.6, 47.4),
    ("paper_50n_8t", "tour_patrol"): (525.1, 377.9),
    ("paper_100n_17t", "random"): (1515.3, 162.3),
    ("paper_100n_17t", "grazing"): (1116.4, 481.8),
    ("paper_200n_41t", "random"): (3676.4, 333.4),
    ("paper_200n_41t", "grazing"): (3276.0, 500.0),
}
GRAPHS = ("paper_50n_8t", "paper_100n_17t", "paper_200n_41t")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("graph_dir", type=Path, help="the folder holding the reference .graphml files")
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--episodes", type=int, default=5)
    parser.add_argument("--steps", type=int, default=500)
    parser.add_argument("--all", action="store_true", help="also run baselines with no reference figure")
    args = parser.parse_args()
    print("| graph | policy | avg_uncertainty | ref | diff | max_neglect | ref | seconds |")
    print("|---|---|---:|---:|---:|---:|---:|---:|")
    for graph in GRAPHS:
        path = args.graph_dir / f"{graph}.graphml"
        if not path.exists():
            raise SystemExit(f"missing reference graph: {path}")
        for policy in BASELINES:
            reference = REFERENCE.get((graph, policy))
            if reference is None and not args.all:
                continue
            start = time.perf_counter()
            results = [
                evaluate(
                    make_team(policy),
                    path,
                    episodes=args.episodes,
                    seed=s * SEED_STRIDE,
                    max_cycles=args.steps,
                )
                for s in range(args.seeds)
            ]
            u = float(pooled_values(results, "avg_uncertainty").mean())
            neglect = float(pooled_values(results, "max_neglect").mean())
            ref_u, ref_n = reference or (float("nan"), float("nan"))
            diff = f"{100 * (u - ref_u) / ref_u:+.1f}%" if reference else ""
            print(
                f"| {graph} | {policy} | {u:.1f} | {ref_u:.1f} | {diff} | {neglect:.1f} | {ref_n:.1f} | "
                f"{time.perf_counter() - start:.1f} |"
            )


if __name__ == "__main__":
    main()
