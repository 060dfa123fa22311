"""The parameter-*sharing* alternative, with SuperSuit and sb3-contrib MaskablePPO.

What it shows, and how it differs from this project's learners:

* **Sharing vs. independence.** :func:`sb3_pm.sharing.make_parameter_sharing_vec_env` turns the
  PettingZoo env into one SB3 ``VecEnv`` (SuperSuit's ``pettingzoo_env_to_vec_env_v1`` +
  ``concat_vec_envs_v1``) whose entries are (env copy, agent) pairs. A *single* network then acts
  for every agent and is trained on all of their experience. That is the usual MARL baseline, but
  it is not decentralized learning: in deployment each agent still acts on its own mental map,
  yet training pools every agent's data into shared weights. ``IndependentPPO`` (the paper's
  setting, see ``train_team_preset.py``) gives each agent its own network, buffer and optimizer,
  sharing nothing.
* **Truncation.** This task never terminates; episodes end by time limit. SB3 bootstraps the
  value of a timed-out step only if its ``info`` says ``TimeLimit.truncated``; SuperSuit's SB3
  wrapper folds ``terminated`` and ``truncated`` into one ``done`` and drops that flag, so every
  episode end would be learned as a true end. Our :class:`~sb3_pm.sharing.MaskedVecEnv` restores
  ``TimeLimit.truncated`` (checked below), accepts the model's seed and serves ``action_masks``
  to MaskablePPO.

Usage::

    python examples/parameter_sharing_supersuit.py --timesteps 20000 --out runs/sharing
    SB3_PM_SMOKE=1 python examples/parameter_sharing_supersuit.py
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import torch
from sb3_contrib import MaskablePPO

from sb3_pm.evaluation import evaluate, markdown_table, resolve_team, summarize
from sb3_pm.sharing import make_parameter_sharing_vec_env
from sb3_pm.sharing.supersuit_vec_env import TRUNCATED_KEY
from sb3_pm.team_interface import Observation, Team


class SharedPolicyTeam(Team):
    """Every agent acts with the one shared model, each from its own observation."""

    name = "shared_ppo"

    def __init__(self, model: MaskablePPO) -> None:
        self.model = model

    def predict_dict(
        self, observations: dict[str, Observation], deterministic: bool = True
    ) -> dict[str, int]:
        actions = {}
        for agent, obs in observations.items():
            action, _ = self.model.predict(
                obs, deterministic=deterministic, action_masks=np.asarray(obs["action_mask"], dtype=bool)
            )
            actions[agent] = int(np.asarray(action).reshape(-1)[0])
        return actions


def check_truncation_flag(venv: Any, max_cycles: int) -> None:
    """Play one episode with masked random moves: the last step must carry TimeLimit.truncated."""
    venv.seed(123)
    venv.reset()
    rng = np.random.default_rng(0)
    for step in range(1, max_cycles + 1):
        masks = np.stack(venv.env_method("action_masks"))
        venv.step_async(np.array([rng.choice(np.flatnonzero(m)) for m in masks]))
        _, _, dones, infos = venv.step_wait()
        if dones.any():
            assert step == max_cycles and all(info.get(TRUNCATED_KEY) for info in infos)
            print(f"episode ended at step {step} with {TRUNCATED_KEY}=True in every entry's info")
            return
    raise AssertionError("the episode did not end at max_cycles")


def main() -> None:
    # One torch thread per process: the networks are small, and two threads beside another
    # process run several times slower than one.
    torch.set_num_threads(1)
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--graph", default="paper-50")
    parser.add_argument("--agents", type=int, default=4)
    parser.add_argument("--timesteps", type=int, default=20_000, help="summed over all agents' entries")
    parser.add_argument("--out", default=None, help="output folder (default: a new temp dir)")
    parser.add_argument("--smoke", action="store_true", help="tiny budget (also: SB3_PM_SMOKE=1)")
    args = parser.parse_args()
    smoke = args.smoke or os.environ.get("SB3_PM_SMOKE") == "1"
    out = Path(args.out or tempfile.mkdtemp(prefix="sb3_pm_sharing_"))
    out.mkdir(parents=True, exist_ok=True)
    n_agents, max_cycles, timesteps, n_steps, episodes = args.agents, 500, args.timesteps, 250, 5
    if smoke:
        n_agents, max_cycles, timesteps, n_steps, episodes = 2, 16, 64, 16, 1

    venv = make_parameter_sharing_vec_env(
        args.graph, n_envs=1, n_agents=n_agents, env_kwargs={"max_cycles": max_cycles}
    )
    check_truncation_flag(venv, max_cycles)
    # One model for all agents: a rollout of n_steps holds n_steps x n_agents transitions.
    model = MaskablePPO("MultiInputPolicy", venv, n_steps=n_steps, batch_size=n_steps, seed=0, verbose=0)
    model.learn(timesteps)
    model.save(out / "shared_model.zip")
    venv.close()

    results = {
        label: [evaluate(team, args.graph, n_agents=n_agents, episodes=episodes, max_cycles=max_cycles)]
        for label, team in (("shared_ppo", SharedPolicyTeam(model)), ("random", resolve_team("random")))
    }
    print(markdown_table(summarize(results)))
    print(f"model saved to {out / 'shared_model.zip'}")


if __name__ == "__main__":
    main()
