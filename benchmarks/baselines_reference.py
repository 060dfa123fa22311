"""Our baselines next to the reference figures of ``sb3_pm/graphs/data/README.md``.

Usage::

    python benchmarks/baselines_reference.py [--seeds 3] [--episodes 5] [--steps 500]

Protocol as the reference: 4 agents, 3 seeds x 5 episodes x 500 steps, random distinct starts.
Seed ``s`` evaluates env seeds ``s * 1000 + e`` (the ``sb3-pm compare`` convention).
"""

from __future__ import annotations

import argparse
import time

from sb3_pm.baselines import BASELINES, make_team
from sb3_pm.evaluation import SEED_STRIDE, evaluate, pooled_values

#: (preset, policy) -> (avg_uncertainty, max_neglect) from that README's table.
REFERENCE = {
    ("paper-50", "random"): (704.8, 110.7),
    ("paper-50", "sit_on_nodes"): (360.4, 500.0),
    ("paper-50", "grazing"): (116.6, 47.4),
    ("paper-50", "tour_patrol"): (525.1, 377.9),
    ("paper-100", "random"): (1515.3, 162.3),
    ("paper-100", "grazing"): (1116.4, 481.8),
    ("paper-200", "random"): (3676.4, 333.4),
    ("paper-200", "grazing"): (3276.0, 500.0),
}
GRAPHS = ("paper-50", "paper-100", "paper-200")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--episodes", type=int, default=5)
    parser.add_argument("--steps", type=int, default=500)
    parser.add_argument("--all", action="store_true", help="also run baselines with no reference figure")
    args = parser.parse_args()
    print("| graph | policy | avg_uncertainty | ref | diff | max_neglect | ref | seconds |")
    print("|---|---|---:|---:|---:|---:|---:|---:|")
    for graph in GRAPHS:
        path = graph  # the published graphs ship with the package
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
