"""An episode as an animated GIF of the rendered graph (env ``render_mode="rgb_array"``, Pillow)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sb3_pm.evaluation.harness import EpisodeRecord, run_episode
from sb3_pm.graphs import GraphLike, resolve_graph
from sb3_pm.team_interface import Team


def record_gif(
    team: Team,
    graph: GraphLike | None,
    path: str | Path,
    n_agents: int | None = None,
    seed: int = 0,
    max_cycles: int = 500,
    env_kwargs: Mapping[str, Any] | None = None,
    fps: int = 8,
    deterministic: bool | None = None,
) -> EpisodeRecord:
    """Play one episode (env seed ``seed``, as episode 0 of ``evaluate(seed=seed)``) and save it.

    ``graph``, ``n_agents`` and ``env_kwargs`` mean what they mean for
    :func:`~sb3_pm.evaluation.evaluate`: a trained team acts on its own graph, with its own size and
    in its own env settings unless told otherwise.

    :param deterministic: passed to ``team.predict``, as in :func:`~sb3_pm.evaluation.evaluate`
        (``None``: the team's ``deploy_temperature`` decides).
    :return: the episode's record, identical to the one :func:`~sb3_pm.evaluation.evaluate` makes.
    """
    path = Path(path)
    if not path.parent.exists():
        raise FileNotFoundError(f"directory for the GIF does not exist: {path.parent}")
    graph = team.default_graph() if graph is None else graph
    spec = resolve_graph(graph)
    n_agents = (team.n_agents or 4) if n_agents is None else int(n_agents)
    kwargs = {**team.env_settings(), **dict(env_kwargs or {})}
    if team.site_bound_pending:  # deploy_filter auto: as evaluate() does
        from sb3_pm.evaluation.neglect_calibration import settle_site_bound

        settle_site_bound(team, spec, n_agents, kwargs, max_cycles)
    env = team.make_env(spec, n_agents=n_agents, max_cycles=max_cycles, render_mode="rgb_array", **kwargs)
    frames: list = []
    try:
        record = run_episode(
            team, env, seed, frames=frames, deterministic=team.acts_deterministically(deterministic)
        )
    finally:
        env.close()
    write_gif(frames, path, fps=fps)
    return record


def write_gif(frames: Sequence[np.ndarray], path: str | Path, fps: int = 8) -> Path:
    """Write ``(H, W, 3)`` uint8 frames as a looping GIF with one palette for every frame.

    A GIF holds at most 256 colours per frame. Quantizing each frame on its own (what a generic
    writer does) was most of the time of a 500-frame GIF; the frames of an episode share one
    picture, so one palette from a sample of frames, applied without dithering, is 3x faster and
    makes a file a third the size.
    """
    from PIL import Image

    if len(frames) == 0:
        raise ValueError("write_gif needs at least one frame")
    sample = np.concatenate(list(frames[:: max(1, len(frames) // 8)]), axis=0)
    palette = Image.fromarray(sample).quantize(colors=255, method=Image.Quantize.MEDIANCUT)
    images = [Image.fromarray(frame).quantize(palette=palette, dither=Image.Dither.NONE) for frame in frames]
    # Pillow takes the frame duration in milliseconds; loop=0 repeats forever.
    images[0].save(path, save_all=True, append_images=images[1:], duration=1000.0 / fps, loop=0)
    return Path(path)
