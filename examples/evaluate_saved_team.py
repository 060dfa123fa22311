"""Evaluate a saved team against the baselines, then plot its uncertainty and record a GIF.

What it shows:

* loading a saved team folder (written by ``IndependentPPO.save`` or ``sb3-pm train``) with
  :func:`sb3_pm.evaluation.resolve_team`, the same call that resolves baseline names;
* :func:`sb3_pm.evaluation.compare`: the trained team and the baselines on the same episodes
  (same env seeds); the trained team runs with the env options it was trained with;
* :func:`sb3_pm.evaluation.plot_uncertainty` (summed target uncertainty per step, one line per
  policy) and :func:`sb3_pm.evaluation.record_gif` (one rendered episode).

Without ``--team`` it first trains a tiny team, so that it runs on its own.
Command-line equivalent:
``sb3-pm compare --policies runs/my_team random local_greedy grazing --out runs/my_comparison``.

Usage::

    python examples/evaluate_saved_team.py --team runs/demo --graph paper-50 --out runs/report
    SB3_PM_SMOKE=1 python examples/evaluate_saved_team.py
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

import torch

from sb3_pm.evaluation import compare, markdown_table, plot_uncertainty, record_gif, resolve_team


def train_tiny_team(graph: str, folder: Path, max_cycles: int) -> Path:
    """A barely trained 2-agent team, so that the example needs no prior run."""
    from sb3_pm import IndependentPPO

    team = IndependentPPO(
        graph,
        n_agents=2,
        env_kwargs={"max_cycles": max_cycles},
        hyperparams={"n_steps": 32, "batch_size": 32, "n_epochs": 1},
        seed=0,
    )
    team.learn(64)
    saved = team.save(folder, overwrite=True)
    team.close()
    return saved


def main() -> None:
    # One torch thread per process: the networks are small, and two threads beside another
    # process run several times slower than one.
    torch.set_num_threads(1)
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--team", default=None, help="a saved team folder (default: train a tiny one)")
    parser.add_argument("--graph", default="paper-50")
    parser.add_argument("--baselines", nargs="+", default=["random", "local_greedy", "grazing"])
    parser.add_argument("--episodes", type=int, default=5)
    parser.add_argument("--max-cycles", type=int, default=500)
    parser.add_argument("--out", default=None, help="output folder (default: a new temp dir)")
    parser.add_argument("--smoke", action="store_true", help="tiny budget (also: SB3_PM_SMOKE=1)")
    args = parser.parse_args()
    smoke = args.smoke or os.environ.get("SB3_PM_SMOKE") == "1"
    out = Path(args.out or tempfile.mkdtemp(prefix="sb3_pm_eval_"))
    out.mkdir(parents=True, exist_ok=True)
    episodes, max_cycles = (1, 24) if smoke else (args.episodes, args.max_cycles)

    team_dir = Path(args.team) if args.team else train_tiny_team(args.graph, out / "team", max_cycles)
    team = resolve_team(team_dir, graph=args.graph)
    n_agents = team.n_agents  # type: ignore[attr-defined]  (a trained team knows its size)

    # Factories: compare builds a fresh team per graph and seed (baselines keep per-episode state).
    factories = {"trained": lambda graph: resolve_team(team_dir, graph=graph)}
    factories.update({name: (lambda graph, name=name: resolve_team(name)) for name in args.baselines})
    comparison = compare(
        factories, [args.graph], seeds=[0], episodes=episodes, n_agents=n_agents, max_cycles=max_cycles
    )
    print(markdown_table(comparison.table))
    plot = plot_uncertainty(
        comparison.results, out / "uncertainty.png", title=f"{args.graph}, {n_agents} agents"
    )
    gif = record_gif(team, args.graph, out / "episode.gif", n_agents=n_agents, seed=0, max_cycles=max_cycles)
    print(f"plot: {plot}\nGIF: {out / 'episode.gif'} (avg uncertainty {gif.metrics['avg_uncertainty']:.1f})")


if __name__ == "__main__":
    main()
