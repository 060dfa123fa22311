"""A fingerprint of everything the environment emits, for checking that a speed-up changes nothing.

    python benchmarks/env_fingerprint.py [--steps 1300] > before.txt   # on the old code
    python benchmarks/env_fingerprint.py [--steps 1300] > after.txt    # on the new code
    diff before.txt after.txt

For each of ten configurations (mental maps and local observations, every reward term, agent
failures, a shared map, illegal moves in ``stay`` mode, a graph family, radius 2 with random initial
uncertainty), a seeded random walk over the allowed moves drives the environment through several
episodes; every observation, reward, termination, truncation and info, and the true state and
metrics after each step, are pickled into one SHA-256 digest per configuration. Equal digests
mean equal outputs bit for bit (same values, dtypes and shapes).
"""

from __future__ import annotations

import argparse
import hashlib
import pickle
from typing import Any

import numpy as np

from sb3_pm.envs import persistent_monitoring_v0

CONFIGS: dict[str, dict[str, Any]] = {
    "map50": {"graph": "paper-50", "reward": {"clearing": 0.04, "collision": 0.001}},
    "paper200": {"graph": "paper-200", "reward": "paper"},
    "every_term": {
        "graph": "paper-50",
        "reward": {
            "collision": 1,
            "momentum": 0.5,
            "change": 0.3,
            "reduction": 0.2,
            "clearing": 0.1,
            "neglect": 0.7,
        },
    },
    "local_r2": {"graph": "paper-50", "observation": "local", "obs_radius": 2},
    "known_8_agents": {"graph": "paper-100", "graph_knowledge": "known", "n_agents": 8},
    "known_targets": {"graph": "paper-50", "target_knowledge": "known"},
    "shared_map": {"graph": "paper-50", "shared_map": True},
    "failures": {
        "graph": "paper-50",
        "failures": {"agent_1": 30},
        "failure_rate": 0.01,
        "reward": {"clearing": 1.0, "collision": 1.0},
    },
    "illegal_stay": {"graph": "paper-50", "illegal_action": "stay"},
    "family": {"graph": "family:er"},
    "radius2_random_u": {"graph": "paper-100", "obs_radius": 2, "initial_uncertainty": "random"},
}


def fingerprint(kwargs: dict[str, Any], steps: int) -> str:
    """The digest of ``steps`` steps (resets included) of one configuration."""
    env = persistent_monitoring_v0.parallel_env(max_cycles=200, **kwargs)
    digest = hashlib.sha256()
    rng = np.random.default_rng(1)

    def feed(value: Any) -> None:
        digest.update(pickle.dumps(value, protocol=4))

    observations, infos = env.reset(seed=3)
    feed((observations, infos))
    for k in range(steps):
        if not env.agents:
            observations, infos = env.reset(seed=None if k % 400 else k)
            feed((observations, infos))
            continue
        actions = {}
        for agent in env.agents:
            allowed = np.flatnonzero(observations[agent]["action_mask"])
            actions[agent] = int(allowed[rng.integers(len(allowed))])
            if kwargs.get("illegal_action") == "stay" and rng.random() < 0.05:
                actions[agent] = int(rng.integers(-3, env.graph.n_nodes + 3))  # some out of range
        outcome = env.step(actions)
        observations = outcome[0]
        feed(outcome)
        feed((env.uncertainty, env.positions, env.episode_metrics()))
    return digest.hexdigest()[:16]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=1300, help="steps per configuration (default 1300)")
    args = parser.parse_args()
    for name, kwargs in CONFIGS.items():
        print(f"{name:18s} {fingerprint(kwargs, args.steps)}", flush=True)


if __name__ == "__main__":
    main()
