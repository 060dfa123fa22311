"""Training speed of an independent team, next to stock SB3 PPO measured in the same run.

    python benchmarks/train_speed.py [--timesteps 1000] [--graphs paper-50 paper-200] [--algo dcbf_ppo]

Prints agent-steps per second (every learner's steps, summed: a 4-agent team at T steps per
learner takes 4T) for a 4-agent team on each graph, and env-steps per second for SB3 PPO
(MlpPolicy) on CartPole-v1 with 8 envs. Both include PPO's train() phases. Short runs: a warm-up
rollout is not timed, so the figures are throughput, not start-up cost.
"""

from __future__ import annotations

import argparse
import time

import torch as th


def team_speed(graph: str, algo: str, timesteps: int, n_envs: int, n_steps: int, threads: int) -> float:
    from sb3_pm.agents.team import IndependentPPO

    team = IndependentPPO(
        graph,
        n_agents=4,
        env_kwargs={"max_cycles": 500},
        algo=algo,
        n_envs=n_envs,
        seed=0,
        hyperparams={"n_steps": n_steps, "batch_size": n_steps, "n_epochs": 5},
    )
    team.learn(n_steps * n_envs)  # warm-up: one rollout and one train() per learner
    start = time.perf_counter()
    team.learn(timesteps, reset_num_timesteps=False)
    elapsed = time.perf_counter() - start
    return team.n_agents * (team.num_timesteps - n_steps * n_envs) / elapsed


def cartpole_speed(timesteps: int) -> float:
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_util import make_vec_env

    env = make_vec_env("CartPole-v1", n_envs=8, seed=0)
    model = PPO("MlpPolicy", env, n_steps=256, batch_size=256, n_epochs=5, seed=0, device="cpu")
    model.learn(2048)
    start = time.perf_counter()
    model.learn(timesteps, reset_num_timesteps=False)
    return (model.num_timesteps - 2048) / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--timesteps", type=int, default=1000, help="timed steps per learner (default 1000)")
    parser.add_argument(
        "--cartpole-timesteps", type=int, default=20480, help="timed CartPole steps (default 20480)"
    )
    parser.add_argument("--graphs", nargs="+", default=["paper-50", "paper-200"])
    parser.add_argument(
        "--algo", default=None, help="dcbf_ppo | maskable_ppo | ppo (default: the team's default)"
    )
    parser.add_argument("--n-envs", type=int, default=2)
    parser.add_argument("--n-steps", type=int, default=250)
    parser.add_argument("--threads", type=int, default=th.get_num_threads(), help="torch threads")
    args = parser.parse_args()
    th.set_num_threads(args.threads)
    from sb3_pm.zoo.registry import default_algo

    algo = args.algo or default_algo()
    print(
        f"torch threads: {args.threads}; team: 4 agents x {algo}, "
        f"n_envs={args.n_envs}, n_steps={args.n_steps}"
    )
    cartpole = cartpole_speed(args.cartpole_timesteps)
    print(f"{'SB3 PPO MlpPolicy CartPole-v1, 8 envs':<48} {cartpole:>10.0f} steps/s")
    for graph in args.graphs:
        speed = team_speed(graph, algo, args.timesteps, args.n_envs, args.n_steps, args.threads)
        paper = 4 * 50_000 / speed
        print(
            f"{f'team {graph} ({algo})':<48} {speed:>10.0f} agent-steps/s   "
            f"paper budget (4 x 50,000): {paper / 60:.1f} min"
        )


if __name__ == "__main__":
    main()
