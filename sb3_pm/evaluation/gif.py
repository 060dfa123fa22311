"""An episode as an animated GIF of the rendered graph (env ``render_mode="rgb_array"``, imageio)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from sb3_pm.baselines.base import Team
from sb3_pm.evaluation.harness import EpisodeRecord, run_episode
from sb3_pm.graphs import GraphLike, resolve_graph


def record_gif(
    team: Team,
    graph: GraphLike,
    path: str | Path,
    n_agents: int = 4,
    seed: int = 0,
    max_cycles: int = 500,
    env_kwargs: Mapping[str, Any] | None = None,
    fps: int = 8,
) -> EpisodeRecord:
    """Play one episode (env seed ``seed``, as episode 0 of ``evaluate(seed=seed)``) and save it.

    :return: the episode's record, identical to the one :func:`~sb3_pm.evaluation.evaluate` makes.
    """
    import imageio.v3 as iio

    from sb3_pm.envs import persistent_monitoring_v0

    path = Path(path)
    if not path.parent.exists():
        raise FileNotFoundError(f"directory for the GIF does not exist: {path.parent}")
    env = persistent_monitoring_v0.parallel_env(
        graph=resolve_graph(graph),
        n_agents=n_agents,
        max_cycles=max_cycles,
        render_mode="rgb_array",
        **dict(env_kwargs or {}),
    )
    frames: list = []
    try:
        record = run_episode(team, env, seed, frames=frames)
    finally:
        env.close()
    # imageio v3's pillow plugin takes the frame duration in milliseconds; loop=0 repeats forever.
    iio.imwrite(path, frames, extension=".gif", duration=1000.0 / fps, loop=0)
    return record
