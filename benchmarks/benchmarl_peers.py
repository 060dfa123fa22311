"""BenchMARL's MAPPO, IPPO and QMIX as peer rows: train on a graph, evaluate on the project's episodes.

Usage (needs the extra ``benchmarl``)::

    python benchmarks/benchmarl_peers.py --algorithms mappo ippo --seeds 0 --lr 3e-4 \\
        --frames 50000 --out results/benchmarl

Each (algorithm, seed) trains with :func:`sb3_pm.integrations.benchmarl_task.make_experiment`
on the task :func:`~sb3_pm.integrations.benchmarl_task.monitoring_task` (the env of the
project's training config as these runs measured it, ``zoo/ippo_split.yml``, for the graph),
for ``--frames`` env steps: one frame moves the whole team, so each agent gets ``--frames``
transitions, the budget ``n_timesteps`` gives each learner of the project's team (50,000 on
``paper-50``). The trained policy then acts as
a :class:`~sb3_pm.team_interface.Team` (:class:`~sb3_pm.integrations.benchmarl_task.BenchMARLTeam`,
deterministic: the most likely legal move) in :func:`sb3_pm.evaluation.evaluate` on env seeds
``--eval-seed .. --eval-seed + --episodes - 1``: with the defaults, the episodes of
``sb3-pm evaluate --graph paper-50 --seed 7 --episodes 10``.

Writes ``<out>/<algorithm>_s<seed>.json`` (``<algorithm>_unshared_s<seed>.json`` with
``--no-share``: one actor per agent, as the project's independent learners, instead of
BenchMARL's default of one for the team): the run's settings, its training and evaluation wall
times, and the evaluation (``sb3-pm evaluate --json``'s schema: per-episode ``avg_uncertainty``
and the other metrics, their means and SDs); BenchMARL's own CSV logs and final checkpoint go to
``<out>/<algorithm>_s<seed>/`` (or ``_unshared``). ``--smoke`` trains 1,000 frames and evaluates
one 50-step episode. Runs on one CPU thread.
"""

from __future__ import annotations

import os

for _variable in ("OMP_NUM_THREADS", "MKL_NUM_THREADS"):  # before torch is imported
    os.environ.setdefault(_variable, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import torch  # noqa: E402

from sb3_pm.errors import InputError  # noqa: E402
from sb3_pm.evaluation import SEED_STRIDE, evaluate  # noqa: E402
from sb3_pm.experiments.record import EVAL_SEED_OFFSET  # noqa: E402
from sb3_pm.integrations.benchmarl_task import (  # noqa: E402
    ALGORITHMS,
    PPO_LOSS,
    PPO_SCHEDULE,
    QMIX_SCHEDULE,
    BenchMARLTeam,
    make_experiment,
    monitoring_task,
)


def run_one(algorithm: str, seed: int, args: argparse.Namespace, out: Path) -> dict[str, Any]:
    """Train ``algorithm`` with ``seed``, evaluate it, write and return its record."""
    torch.set_num_threads(1)
    task = monitoring_task(args.graph, n_agents=args.agents)
    stem = f"{algorithm}{'' if args.share else '_unshared'}_s{seed}"
    folder = out / stem
    folder.mkdir(parents=True, exist_ok=True)
    experiment = make_experiment(
        algorithm, task, seed, args.frames, args.lr, str(folder), share_policy_params=args.share
    )
    start = time.perf_counter()
    experiment.run()
    train_seconds = time.perf_counter() - start
    torch.set_num_threads(1)  # closing TorchRL's SerialEnv raises torch's thread count
    team = BenchMARLTeam.from_experiment(experiment, task, name=f"benchmarl_{algorithm}")
    eval_seed = EVAL_SEED_OFFSET + seed * SEED_STRIDE if args.reproduce_episodes else args.eval_seed
    start = time.perf_counter()
    result = evaluate(
        team, args.graph, episodes=args.episodes, seed=eval_seed, max_cycles=args.eval_steps
    )
    eval_seconds = time.perf_counter() - start
    tuning = None
    if args.tune_episodes:
        tuning = evaluate(
            team,
            args.graph,
            episodes=args.tune_episodes,
            seed=args.tune_seed,
            max_cycles=args.eval_steps,
        ).to_dict()
    record = {
        "algorithm": algorithm,
        "seed": seed,
        "graph": args.graph,
        "n_agents": args.agents,
        "frames": args.frames,
        "lr": args.lr,
        "share_policy_params": args.share,
        "schedule": PPO_SCHEDULE if algorithm != "qmix" else QMIX_SCHEDULE,
        "ppo_loss": PPO_LOSS if algorithm != "qmix" else None,
        "task": task.config,
        "train_seconds": round(train_seconds, 1),
        "eval_seconds": round(eval_seconds, 1),
        "command": " ".join([Path(sys.executable).name, *sys.argv]),
        "eval_seed": eval_seed,
        "evaluation": result.to_dict(),
        "tuning_evaluation": tuning,
    }
    path = out / f"{stem}.json"
    partial = path.with_suffix(".json.part")
    partial.write_text(json.dumps(record, indent=1, default=str) + "\n")
    partial.replace(path)
    return record


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--algorithms", nargs="+", default=["mappo", "ippo"], choices=ALGORITHMS)
    parser.add_argument("--seeds", nargs="+", type=int, default=[0])
    parser.add_argument("--lr", type=float, default=3e-4)
    parser.add_argument("--frames", type=int, default=50_000, help="env steps (each agent's transitions)")
    parser.add_argument("--graph", default="paper-50")
    parser.add_argument("--agents", type=int, default=4)
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--eval-seed", type=int, default=7)
    parser.add_argument(
        "--reproduce-episodes",
        action="store_true",
        help="evaluate seed S on sb3-pm reproduce's episodes for training seed S "
        "(env seeds EVAL_SEED_OFFSET + S * SEED_STRIDE + e), not on --eval-seed",
    )
    parser.add_argument(
        "--tune-episodes",
        type=int,
        default=0,
        help="also evaluate on this many held-out tuning episodes (env seeds from --tune-seed), "
        "recorded as tuning_evaluation: choose settings on these, report the others",
    )
    parser.add_argument("--tune-seed", type=int, default=900)
    parser.add_argument("--eval-steps", type=int, default=500)
    parser.add_argument("--out", type=Path, default=Path("results/benchmarl"))
    parser.add_argument(
        "--no-share",
        dest="share",
        action="store_false",
        help="one actor and critic per agent, not one for the team (records: <algorithm>_unshared_s<seed>)",
    )
    parser.add_argument("--smoke", action="store_true", help="1,000 frames, one 50-step episode")
    args = parser.parse_args(argv)
    if args.smoke:
        args.frames, args.episodes, args.eval_steps = 1000, 1, 50
    torch.set_num_threads(1)
    try:
        for algorithm in args.algorithms:
            for seed in args.seeds:
                record = run_one(algorithm, seed, args, args.out)
                mean = record["evaluation"]["mean"]["avg_uncertainty"]
                sd = record["evaluation"]["std"]["avg_uncertainty"]
                tuning = record["tuning_evaluation"]
                tuned = (
                    f"; tuning episodes {tuning['mean']['avg_uncertainty']:.1f}" if tuning else ""
                )
                print(
                    f"{algorithm} seed {seed}: avg_uncertainty {mean:.1f} ± {sd:.1f} "
                    f"({args.episodes} episodes){tuned}; trained in {record['train_seconds']:.0f} s"
                )
    except InputError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
