"""What training costs on a large site: agent-steps per second and peak memory of ``sb3-pm train``.

Run: ``python benchmarks/train_scale.py [--cells paper-200:dense:4 city-1k:edges:12]
[--config ippo_transfer] [--timesteps 1000] [--hyperparams KEY:VALUE ...]``.

Each cell ``GRAPH:LAYOUT:AGENTS`` runs in its own process (one torch thread), so its peak resident
memory (``VmHWM``, the process image's own) is its own. It builds the team as ``sb3-pm train
--config CONFIG --env GRAPH --env-kwargs layout:LAYOUT --hyperparams n_agents:AGENTS ...`` does
(:meth:`IndependentPPO.from_config`, the same config and overrides), then trains it for
``--timesteps`` steps per learner (rollouts and updates both) and reports the team's agent-steps per
second of ``learn()`` (agents x timesteps / seconds; the build is timed apart) and the peak memory.
``--timesteps`` is rounded up by SB3 to whole rollouts (``n_steps x n_envs`` per learner).

``--hyperparams`` applies to every cell (e.g. ``batch_size:50``), as ``sb3-pm train
--hyperparams`` does; ``--update-slots K`` lets at most K learners update at once (default: one
per core, as ``sb3-pm train``). The ratio of the cells' agent-steps per second is what
docs/RESULTS.md reports ("Sites of thousands of nodes").
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from typing import Any


def cell(
    graph_name: str,
    layout: str,
    agents: int,
    config_name: str,
    timesteps: int,
    overrides: dict[str, Any],
    update_slots: int | None,
) -> dict[str, Any]:
    """One training measurement, in this process."""
    import torch

    torch.set_num_threads(1)
    from sb3_pm.agents.training.team import IndependentPPO
    from sb3_pm.graphs import resolve_graph_or_family
    from sb3_pm.zoo import load_config

    start = time.perf_counter()
    graph = resolve_graph_or_family(graph_name)
    env_kwargs = {**overrides.pop("env_kwargs", {}), "layout": layout}
    config = load_config(config_name, graph_name, {**overrides, "n_agents": agents, "env_kwargs": env_kwargs})
    team = IndependentPPO.from_config(config, graph, seed=0)
    team.update_slots = update_slots
    built = time.perf_counter() - start
    start = time.perf_counter()
    team.learn(timesteps)
    seconds = time.perf_counter() - start
    done = team.num_timesteps
    team.close()
    status = open("/proc/self/status", encoding="utf-8").read()
    return {
        "graph": graph_name,
        "layout": layout,
        "agents": agents,
        "timesteps": done,
        "build_s": built,
        "learn_s": seconds,
        "agent_steps_per_s": agents * done / seconds,
        "peak_mb": int(status.split("VmHWM:")[1].split()[0]) / 1024,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cells", nargs="+", default=["paper-200:dense:4", "city-1k:edges:12"],
                        help="GRAPH:LAYOUT:AGENTS per cell (default paper-200:dense:4 city-1k:edges:12)")
    parser.add_argument("--config", default="ippo_transfer", help="a shipped config or a YAML path")
    parser.add_argument("--timesteps", type=int, default=1000, help="steps per learner (default 1000)")
    parser.add_argument("--hyperparams", nargs="*", default=[], metavar="KEY:VALUE",
                        help="config overrides for every cell, as sb3-pm train's (VALUE is YAML)")
    parser.add_argument("--update-slots", type=int, default=None, help="learners updating at once")
    parser.add_argument("--json", default=None, help="also write the rows to this file")
    parser.add_argument("--cell", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    from sb3_pm.commands.train import parse_overrides

    if args.cell:
        graph_name, layout, agents = args.cell.rsplit(":", 2)
        overrides = parse_overrides(args.hyperparams, "--hyperparams")
        row = cell(graph_name, layout, int(agents), args.config, args.timesteps, overrides, args.update_slots)
        print(json.dumps(row))
        return
    environment = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    rows = []
    print(f"{'graph':>10} {'layout':>6} {'agents':>6} {'steps':>6} {'build s':>8} {'learn s':>8} "
          f"{'agent-steps/s':>13} {'peak MB':>8}")
    for spec in args.cells:
        command = [sys.executable, __file__, "--cell", spec, "--config", args.config]
        command += ["--timesteps", str(args.timesteps)]
        command += ["--hyperparams", *args.hyperparams] if args.hyperparams else []
        command += [] if args.update_slots is None else ["--update-slots", str(args.update_slots)]
        done = subprocess.run(command, capture_output=True, text=True, env=environment)
        if done.returncode != 0:
            last = (done.stderr.strip().splitlines() or [f"exit status {done.returncode}"])[-1]
            print(f"{spec:>24} failed: {last}")
            continue
        row = json.loads(done.stdout.strip().splitlines()[-1])
        rows.append(row)
        print(f"{row['graph']:>10} {row['layout']:>6} {row['agents']:>6} {row['timesteps']:>6} "
              f"{row['build_s']:>8.1f} {row['learn_s']:>8.1f} {row['agent_steps_per_s']:>13.1f} "
              f"{row['peak_mb']:>8.0f}")
    if len(rows) == 2:
        print(f"ratio {rows[1]['graph']} / {rows[0]['graph']}: "
              f"{rows[1]['agent_steps_per_s'] / rows[0]['agent_steps_per_s']:.2f}")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as handle:
            json.dump(rows, handle, indent=2)


if __name__ == "__main__":
    main()
