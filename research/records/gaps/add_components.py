"""Add the components bound (docs/PLANNING.md, "By components") to recorded ``sb3-pm bound --planner``
files, each episode's recorded planner score as the ceiling; ``lower_bound`` and
``planner_x_bound`` become the largest bound's. Files that already have it are left as they are.

Usage::

    python research/records/gaps/add_components.py research/records/gaps/paper-50_s*.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from sb3_pm.envs import persistent_monitoring_v0
from sb3_pm.files import write_atomic
from sb3_pm.planning import component_bound


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("files", nargs="+", type=Path)
    for path in parser.parse_args().files:
        payload = json.loads(path.read_text())
        if all("components" in row for row in payload["rows"]):
            continue
        env = persistent_monitoring_v0.parallel_env(
            graph=payload["graph"], n_agents=payload["agents"], max_cycles=payload["steps"]
        )
        for row in payload["rows"]:
            env.reset(seed=row["env_seed"])
            state = env.unwrapped
            row["components"] = component_bound(
                state.graph, state.positions, payload["steps"], state.u_max, state.uncertainty, ceiling=row["planner"]
            )
            found = [row[k] for k in ("stepwise", "priced", "components") if row[k] is not None]
            row["lower_bound"] = max(found)
            row["planner_x_bound"] = row["planner"] / row["lower_bound"]
            print(path.name, row["env_seed"], row["components"], row["planner"], flush=True)
        columns = ["stepwise", "priced", "components", "lower_bound", "planner", "planner_x_bound"]
        payload["means"] = {
            c: (None if any(r[c] is None for r in payload["rows"]) else float(np.mean([r[c] for r in payload["rows"]])))
            for c in columns
        }
        write_atomic(path, json.dumps(payload, indent=2))


if __name__ == "__main__":
    main()
