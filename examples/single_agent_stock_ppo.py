"""Use the single-agent Gymnasium view with stock Stable-Baselines3 PPO (and sb3-contrib MaskablePPO).

What it shows:

* ``import sb3_pm`` registers Gymnasium ids such as ``sb3_pm/PersistentMonitoring-paper50-v0``:
  one learning agent with its mental-map ``Dict`` observation, its teammates driven by a fixed
  team (``teammates="random" | "local_greedy" | "grazing" | <saved team folder>``);
* stock ``PPO("MultiInputPolicy", env)`` trains on it with no glue code (an illegal move simply
  stays put), and so does ``MaskablePPO``, which reads the env's ``action_masks()``;
* the last step's ``info["metrics"]`` holds the episode's metrics.

The same env in rl-zoo: ``python -m rl_zoo3.train --gym-packages sb3_pm --algo ppo
--env sb3_pm/PersistentMonitoring-paper50-v0 -conf zoo/ppo.yml`` (see docs/INTEGRATION.md).

Usage::

    python examples/single_agent_stock_ppo.py --timesteps 50000 --out runs/single_agent
    SB3_PM_SMOKE=1 python examples/single_agent_stock_ppo.py
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

import gymnasium as gym
import torch
from sb3_contrib import MaskablePPO
from stable_baselines3 import PPO

import sb3_pm  # noqa: F401  (registers the sb3_pm/... Gymnasium ids)

ENV_ID = "sb3_pm/PersistentMonitoring-paper50-v0"


def run_episode(model: PPO, env: gym.Env, seed: int, masked: bool) -> dict[str, float]:
    """One deterministic episode; returns the env's end-of-episode metrics."""
    observation, _ = env.reset(seed=seed)
    while True:
        if masked:
            action, _ = model.predict(
                observation, deterministic=True, action_masks=env.unwrapped.action_masks()
            )
        else:
            action, _ = model.predict(observation, deterministic=True)
        observation, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            return info["metrics"]


def main() -> None:
    # One torch thread per process: the networks are small, and two threads beside another
    # process run several times slower than one.
    torch.set_num_threads(1)
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--env", default=ENV_ID)
    parser.add_argument("--teammates", default="local_greedy")
    parser.add_argument("--timesteps", type=int, default=20_000)
    parser.add_argument("--out", default=None, help="output folder (default: a new temp dir)")
    parser.add_argument("--smoke", action="store_true", help="tiny budget (also: SB3_PM_SMOKE=1)")
    args = parser.parse_args()
    smoke = args.smoke or os.environ.get("SB3_PM_SMOKE") == "1"
    out = Path(args.out or tempfile.mkdtemp(prefix="sb3_pm_single_"))
    out.mkdir(parents=True, exist_ok=True)
    max_cycles, timesteps, n_steps = (32, 64, 32) if smoke else (500, args.timesteps, 500)

    for algo, masked in ((PPO, False), (MaskablePPO, True)):
        env = gym.make(args.env, teammates=args.teammates, max_cycles=max_cycles)
        model = algo(
            "MultiInputPolicy", env, n_steps=n_steps, batch_size=min(n_steps, 100), seed=0, verbose=0
        )
        model.learn(timesteps)
        path = out / f"{algo.__name__.lower()}.zip"
        model.save(path)
        metrics = run_episode(model, env, seed=1000, masked=masked)
        print(f"{algo.__name__:12s} saved to {path}; avg uncertainty {metrics['avg_uncertainty']:.1f}")
        env.close()


if __name__ == "__main__":
    main()
