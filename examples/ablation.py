"""A short ablation: the same team with and without the DCBF safety filter (or the estimator).

What it shows:

* ablations are flags, not copied model files: every variant is ``IndependentPPO`` with the same
  hyperparameters but one ``policy_kwargs`` switch (``use_dcbf``, ``use_estimator``,
  ``avoid_collisions`` ..., see docs/CONFIG.md);
* the same seeds for every variant, and :func:`sb3_pm.evaluation.summarize` / ``anova`` over the
  evaluation episodes.

For multi-seed grids with resumable cells, use the experiments runner and
``zoo/experiments/ablation.yml`` instead (``sb3-pm reproduce``).

Usage::

    python examples/ablation.py --flag use_dcbf --timesteps 20000 --out runs/ablation
    SB3_PM_SMOKE=1 python examples/ablation.py
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

import torch

from sb3_pm import IndependentPPO
from sb3_pm.evaluation import anova_text, evaluate, markdown_table, summarize
from sb3_pm.evaluation.statistics import anova

FLAGS = ("use_dcbf", "use_estimator", "avoid_collisions")


def main() -> None:
    # One torch thread per process: the networks are small, and two threads beside another
    # process run several times slower than one.
    torch.set_num_threads(1)
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--flag", choices=FLAGS, default="use_dcbf", help="the DCBFPolicy switch to ablate")
    parser.add_argument("--graph", default="paper-50")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--timesteps", type=int, default=20_000, help="per learner")
    parser.add_argument("--episodes", type=int, default=5)
    parser.add_argument("--out", default=None, help="output folder (default: a new temp dir)")
    parser.add_argument("--smoke", action="store_true", help="tiny budget (also: SB3_PM_SMOKE=1)")
    args = parser.parse_args()
    smoke = args.smoke or os.environ.get("SB3_PM_SMOKE") == "1"
    out = Path(args.out or tempfile.mkdtemp(prefix="sb3_pm_ablation_"))
    out.mkdir(parents=True, exist_ok=True)

    n_agents, max_cycles, timesteps, episodes, seeds = 4, 500, args.timesteps, args.episodes, args.seeds
    hyperparams = {"n_steps": 250, "batch_size": 250, "n_epochs": 5, "learning_rate": "lin_3e-4"}
    if smoke:
        n_agents, max_cycles, timesteps, episodes, seeds = 2, 16, 32, 1, [0]
        hyperparams.update(n_steps=16, batch_size=16, n_epochs=1)

    results: dict[str, list] = {}
    for value in (True, False):
        label = f"{args.flag}={value}"
        for seed in seeds:
            team = IndependentPPO(
                args.graph,
                n_agents=n_agents,
                algo="dcbf_ppo",
                env_kwargs={"max_cycles": max_cycles},
                hyperparams={**hyperparams, "policy_kwargs": {args.flag: value}},
                seed=seed,
            )
            team.learn(timesteps)
            team.save(out / f"{label}_seed{seed}", overwrite=True)
            results.setdefault(label, []).append(
                evaluate(team, args.graph, n_agents=n_agents, episodes=episodes, seed=1000 * (seed + 1),
                         max_cycles=max_cycles, policy_name=label)
            )  # fmt: skip
            team.close()

    table = summarize(results)
    (out / "table.md").write_text(markdown_table(table))
    print(markdown_table(table))
    if sum(len(r.episodes) for rs in results.values() for r in rs) > len(results):
        print(anova_text([anova(results, "avg_uncertainty")]))  # needs more than one episode per variant
    print(f"teams and table in {out}")


if __name__ == "__main__":
    main()
