"""Where an environment step goes: cProfile of ``benchmarks/env_speed.py``'s loop on a graph.

    python docs/results/speed_probes/env_step_profile.py [paper-200] [3000]

Prints, for each function of the package the step calls, its cumulative time per call in
microseconds (the profiler's own overhead included, so the figures are larger than the
benchmark's).
"""

import cProfile
import pstats
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "benchmarks"))
import env_speed  # noqa: E402  (benchmarks/ is not a package)

graph = sys.argv[1] if len(sys.argv) > 1 else "paper-200"
steps = int(sys.argv[2]) if len(sys.argv) > 2 else 3000
env_speed.measure(graph, 4, 200, "map")  # warm-up: imports, graph loading
profiler = cProfile.Profile()
profiler.runcall(env_speed.measure, graph, 4, steps, "map")
stats = pstats.Stats(profiler).stats  # type: ignore[attr-defined]
rows = []
for (filename, _, name), (_, calls, _, cumulative, _) in stats.items():
    if "sb3_pm" in filename and calls >= steps:
        rows.append((cumulative / calls * 1e6, calls / steps, f"{Path(filename).name}:{name}"))
print(f"{graph}, {steps} steps, 4 agents, mental maps")
print(f"{'function':<48} {'µs per call':>12} {'calls per step':>15}")
for per_call, per_step, label in sorted(rows, reverse=True):
    print(f"{label:<48} {per_call:12.1f} {per_step:15.2f}")
