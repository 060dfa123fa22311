"""Train a team of independent DCBF-PPO learners on a preset graph, save it, and evaluate it.

What it shows:

* reading an entry of the default team config ``ippo`` (the repository's ``zoo/ippo.yml``, shipped
  with the package; rl-zoo conventions: keyed by graph, ``default:`` fallback, ``lin_``
  schedules) with :func:`sb3_pm.zoo.load_config`;
* building the team with :meth:`IndependentPPO.from_config`: one learner per agent, sharing
  nothing (the paper's fully decentralized setting);
* ``learn`` / ``save`` and :func:`sb3_pm.evaluation.evaluate` with the paper's metrics.

The same run from the command line: ``sb3-pm train --env paper-50``.

Usage::

    python examples/train_team_preset.py --graph paper-50 --out runs/example_team
    SB3_PM_SMOKE=1 python examples/train_team_preset.py      # a few seconds, into a temp dir
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

import torch

from sb3_pm import IndependentPPO
from sb3_pm.evaluation import evaluate, markdown_table, summarize
from sb3_pm.zoo import load_config


def main() -> None:
    # One torch thread per process: the networks are small, and two threads beside another
    # process run several times slower than one.
    torch.set_num_threads(1)
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--graph", default="paper-50", help="preset name or .graphml path")
    parser.add_argument("--config", default="ippo", help="team config: a path or shipped name (default ippo)")
    parser.add_argument("--timesteps", type=int, default=None, help="per learner (default: the config's)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default=None, help="output folder (default: a new temp dir)")
    parser.add_argument("--smoke", action="store_true", help="tiny budget (also: SB3_PM_SMOKE=1)")
    args = parser.parse_args()
    smoke = args.smoke or os.environ.get("SB3_PM_SMOKE") == "1"
    out = Path(args.out or tempfile.mkdtemp(prefix="sb3_pm_team_"))

    config = load_config(args.config, args.graph)
    timesteps = args.timesteps or config.n_timesteps
    episodes, max_cycles = 5, int(config.env_kwargs.get("max_cycles", 500))
    if smoke:
        # Two agents, 32-step episodes, one tiny rollout: exercises every step in seconds.
        config.n_agents, config.n_envs = 2, 1
        config.hyperparams.update(n_steps=32, batch_size=32, n_epochs=1)
        config.env_kwargs["max_cycles"] = max_cycles = 32
        timesteps, episodes = 64, 1

    team = IndependentPPO.from_config(config, graph=args.graph, seed=args.seed)
    print(f"training {team} for {timesteps} steps per learner (config entry {config.entry!r})")
    team.learn(timesteps)
    saved = team.save(out / "team", overwrite=True)
    print(f"saved the team to {saved}")

    result = evaluate(
        team, args.graph, n_agents=team.n_agents, episodes=episodes, seed=1000, max_cycles=max_cycles
    )
    print(markdown_table(summarize({"ippo": [result]})))
    team.close()


if __name__ == "__main__":
    main()
