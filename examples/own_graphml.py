"""Bring your own graph: write a GraphML file, then train and evaluate a team on it.

What it shows:

* drawing a connected Erdős–Rényi graph with targets (:func:`sb3_pm.graphs.erdos_renyi`) and
  writing it with :func:`sb3_pm.graphs.save_graphml`. Any GraphML file works the same way:
  undirected, connected, with a boolean node attribute ``target`` (see ``sb3_pm/graphs/io.py``);
* passing the ``.graphml`` path wherever a graph is expected (``IndependentPPO``, ``evaluate``,
  ``sb3-pm train --env my_graph.graphml``, ``gym.make(..., graph=path)``);
* saving the team (a non-preset graph is saved with it as ``graph.graphml``) and loading it back
  with :func:`sb3_pm.evaluation.resolve_team`, which checks it is the same graph.

Usage::

    python examples/own_graphml.py --out runs/own_graph
    SB3_PM_SMOKE=1 python examples/own_graphml.py
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

import torch

from sb3_pm import IndependentPPO
from sb3_pm.evaluation import evaluate, markdown_table, resolve_team, summarize
from sb3_pm.graphs import erdos_renyi, resolve_graph, save_graphml


def main() -> None:
    # One torch thread per process: the networks are small, and two threads beside another
    # process run several times slower than one.
    torch.set_num_threads(1)
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--nodes", type=int, default=30)
    parser.add_argument("--targets", type=int, default=5)
    parser.add_argument("--timesteps", type=int, default=20_000, help="per learner")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default=None, help="output folder (default: a new temp dir)")
    parser.add_argument("--smoke", action="store_true", help="tiny budget (also: SB3_PM_SMOKE=1)")
    args = parser.parse_args()
    smoke = args.smoke or os.environ.get("SB3_PM_SMOKE") == "1"
    out = Path(args.out or tempfile.mkdtemp(prefix="sb3_pm_graph_"))
    out.mkdir(parents=True, exist_ok=True)

    # 1. A graph of our own, written as GraphML (the file stem names it in reports and configs).
    spec = erdos_renyi(args.nodes, edge_prob=0.15, n_targets=args.targets, seed=args.seed, name="my_graph")
    path = save_graphml(spec, out / "my_graph.graphml", overwrite=True)
    loaded = resolve_graph(path)
    print(f"wrote {path}: {loaded.n_nodes} nodes, {int(loaded.targets.sum())} targets")

    # 2. A team trained on the file. maskable_ppo keeps this example light; dcbf_ppo is the default.
    n_agents, max_cycles, episodes, timesteps = 3, 200, 5, args.timesteps
    hyperparams = {"n_steps": 200, "batch_size": 200, "n_epochs": 5, "learning_rate": "lin_3e-4"}
    if smoke:
        n_agents, max_cycles, episodes, timesteps = 2, 32, 1, 64
        hyperparams.update(n_steps=32, batch_size=32, n_epochs=1)
    team = IndependentPPO(
        path,
        n_agents=n_agents,
        algo="maskable_ppo",
        env_kwargs={"max_cycles": max_cycles},
        hyperparams=hyperparams,
        seed=args.seed,
    )
    team.learn(timesteps)
    folder = team.save(out / "team", overwrite=True)
    team.close()

    # 3. Load it back against the same file and compare with a baseline.
    trained = resolve_team(folder, graph=path)
    results = {
        "trained": [evaluate(trained, path, n_agents=n_agents, episodes=episodes, max_cycles=max_cycles)],
        "random": [
            evaluate(
                resolve_team("random"), path, n_agents=n_agents, episodes=episodes, max_cycles=max_cycles
            )
        ],
    }
    print(markdown_table(summarize(results)))
    print(f"outputs in {out}")


if __name__ == "__main__":
    main()
