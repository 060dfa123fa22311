"""Evaluation speed of a learned team, and of writing an episode's GIF.

    python benchmarks/eval_speed.py [--graphs paper-50 paper-200] [--episodes 2] [--steps 500]
                                    [--config ippo] [--threads 1 2] [--repeats 3] [--gif-frames 500]
                                    [--inference serial stacked] [--team DIR]
                                    [--devices cpu cuda]

For each graph, builds a 4-agent team from the config (untrained: its forward passes cost what a
trained team's do) and times ``evaluate`` with each torch thread count, in episodes per second of
``--steps`` steps, with one warm-up episode not timed; each figure is the median of ``--repeats``
timed runs (the development machine is a shared VM, and single runs varied by 20%).
``--inference`` times the team
acting one forward pass per agent (``serial``) and one forward pass for the whole team
(``stacked``, the default, :mod:`sb3_pm.agents.deployment.team_forward`; the same actions, bit for bit), and
prints their ratios to ``serial``. ``--team DIR`` times a trained team instead of an untrained one
(on each graph of ``--graphs``; one trained elsewhere is deployed there if it transfers, with its
own team size). Then renders and writes a GIF
of ``--gif-frames`` frames on the first graph (drawing and writing timed separately). ``--devices`` runs
the team's forward passes on each torch device listed (``cpu``, ``cuda``); the environment and the
baselines stay on the CPU. The load
average is printed: on a shared CPU the figures are lower.

Measured on the 2-core development machine, idle, with torch 2.13.0 (see the README's Speed
section for the figures and the command).
"""

from __future__ import annotations

import argparse
import itertools
import os
import tempfile
import time
from pathlib import Path


def evaluation_speed(
    graph: str,
    config: str,
    episodes: int,
    steps: int,
    threads: int,
    repeats: int,
    inference: str = "stacked",
    team_path: str | None = None,
    device: str = "cpu",
) -> float:
    """Episodes per second of a learned team on ``graph`` with ``threads`` torch threads (the
    median of ``repeats`` timed runs): a 4-agent team built from ``config``, or the saved team
    ``team_path``."""
    import statistics

    from sb3_pm.agents.training.team import IndependentPPO
    from sb3_pm.evaluation import evaluate
    from sb3_pm.zoo import load_config

    if team_path is not None:
        from sb3_pm.evaluation.teams import load_trained_team

        team = load_trained_team(team_path, graph=graph, device=device)
        env_kwargs = {k: v for k, v in team.env_kwargs.items() if k != "max_cycles"}  # type: ignore[attr-defined]
    else:
        entry = load_config(config, graph)
        team = IndependentPPO.from_config(entry, graph, seed=0, device=device)
        env_kwargs = {}
    team.stacked_inference = inference != "serial"  # type: ignore[attr-defined]
    n_agents = team.n_agents  # type: ignore[attr-defined]
    run = dict(n_agents=n_agents, max_cycles=steps, threads=threads, env_kwargs=env_kwargs)
    evaluate(team, graph, episodes=1, **run)  # warm-up
    rates = []
    for _ in range(repeats):
        start = time.perf_counter()
        evaluate(team, graph, episodes=episodes, seed=1, **run)
        rates.append(episodes / (time.perf_counter() - start))
    close = getattr(team, "close", None)
    if close is not None:
        close()
    return statistics.median(rates)


def gif_speed(graph: str, frames: int) -> tuple[float, float]:
    """Seconds to draw ``frames`` frames of ``graph`` and to write them as a GIF."""
    import numpy as np

    from sb3_pm.envs.rendering import GraphRenderer
    from sb3_pm.evaluation.gif import write_gif
    from sb3_pm.graphs import resolve_graph

    spec = resolve_graph(graph)
    renderer = GraphRenderer(spec, u_max=100)
    rng = np.random.default_rng(0)
    start = time.perf_counter()
    images = [
        renderer.draw(rng.integers(0, 101, spec.n_nodes), rng.choice(spec.n_nodes, 4, replace=False), k)
        for k in range(frames)
    ]
    drawn = time.perf_counter()
    renderer.close()
    with tempfile.TemporaryDirectory() as folder:
        write_gif(images, Path(folder) / "episode.gif")
    return drawn - start, time.perf_counter() - drawn


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--graphs", nargs="+", default=["paper-50", "paper-200"])
    parser.add_argument("--episodes", type=int, default=2)
    parser.add_argument("--steps", type=int, default=500)
    parser.add_argument("--config", default="ippo")
    parser.add_argument("--threads", nargs="+", type=int, default=[1, 2])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--gif-frames", type=int, default=500)
    parser.add_argument(
        "--inference", nargs="+", choices=["serial", "stacked"], default=["serial", "stacked"]
    )
    parser.add_argument("--team", default=None, help="time this saved team instead of an untrained one")
    parser.add_argument("--devices", nargs="+", default=["cpu"], help="torch devices (default cpu)")
    args = parser.parse_args()
    import torch

    if "cuda" in args.devices and not torch.cuda.is_available():
        parser.error("--devices cuda: torch sees no CUDA device here")

    print(f"torch {torch.__version__}, {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}")
    team = f"the saved team {args.team}" if args.team else f"an untrained 4-agent team ({args.config})"
    print(f"{team}, {args.episodes} episodes of {args.steps} steps per timed run")
    print(
        "| graph | device | inference | torch threads | episodes/s | seconds per episode "
        "| × serial |"
    )
    print("|---|---|---|---:|---:|---:|---:|")
    for graph in args.graphs:
        for device, threads in itertools.product(args.devices, args.threads):
            serial = None
            for inference in args.inference:
                rate = evaluation_speed(
                    graph,
                    args.config,
                    args.episodes,
                    args.steps,
                    threads,
                    args.repeats,
                    inference,
                    args.team,
                    device,
                )
                serial = rate if inference == "serial" else serial
                ratio = f"{rate / serial:.2f}" if serial else "—"
                row = f"| {graph} | {device} | {inference} | {threads} | {rate:.3f}"
                row += f" | {1 / rate:.2f}"
                print(f"{row} | {ratio} |", flush=True)
    if args.gif_frames > 0:
        draw, write = gif_speed(args.graphs[0], args.gif_frames)
        print(
            f"\nGIF of {args.gif_frames} frames on {args.graphs[0]}: drawn in {draw:.1f} s "
            f"({args.gif_frames / draw:.0f} frames/s), written in {write:.1f} s"
        )


if __name__ == "__main__":
    main()
