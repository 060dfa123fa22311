"""An episode as an animated GIF of the rendered graph (env ``render_mode="rgb_array"``, Pillow).

Frames go to disk as they are drawn (:class:`GifWriter`): a 500-step episode of a 50-node graph
draws about 340 MB of frames, which the first version held in memory until the episode ended. The
file is written under a temporary name and renamed at the end
(:func:`~sb3_pm.files.atomic_path`): a GIF stopped half way (Ctrl-C, a full disk) leaves the
previous file, not half of one.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

import numpy as np

from sb3_pm.evaluation.harness import EpisodeRecord, run_episode, torch_threads
from sb3_pm.files import atomic_path
from sb3_pm.graphs import GraphLike, resolve_graph
from sb3_pm.team_interface import Team

#: The palette index of a delta frame's unchanged pixels: the palette has 255 colours, so it is free.
TRANSPARENT = 255


class GifWriter:
    """Appends ``(H, W, 3)`` uint8 frames to an open GIF file, one at a time, keeping none of them.

    A GIF holds at most 256 colours per frame. Quantizing each frame on its own (what a generic
    writer does) was most of the time of a 500-frame GIF; the frames of an episode share one
    picture, so one palette, applied without dithering, is 3x faster and makes a file a third the
    size. A stream cannot sample frames it has not seen yet, so the palette is taken from the first
    frame and ``palette_sample``: a picture with every colour the later frames can hold (for an
    episode, the graph with its targets at every level of uncertainty, :func:`episode_colors`).

    Each frame after the first is stored as the rectangle that changed since the frame before it
    (the previous frame's palette indices are the only image kept, 1 byte a pixel).
    """

    def __init__(self, handle: IO[bytes], fps: int = 8, palette_sample: np.ndarray | None = None) -> None:
        self.handle = handle
        #: Pillow takes the frame duration in milliseconds
        self.duration = 1000.0 / fps
        self.palette_sample = palette_sample
        #: frames written so far
        self.frames = 0
        self._palette: Any = None
        self._previous: np.ndarray | None = None

    def append(self, frame: np.ndarray) -> None:
        """Quantize ``frame`` to the file's palette and write it."""
        from PIL import GifImagePlugin, Image

        if self._palette is None:
            sample = frame if self.palette_sample is None else np.concatenate([frame, self.palette_sample])
            self._palette = Image.fromarray(sample).quantize(colors=255, method=Image.Quantize.MEDIANCUT)
        image = Image.fromarray(frame).quantize(palette=self._palette, dither=Image.Dither.NONE)
        indices = np.asarray(image)
        if self._previous is None:
            # the global palette, and loop=0: repeat forever
            header, _ = GifImagePlugin.getheader(image, info={"loop": 0, "duration": self.duration})
            self.handle.write(b"".join(header))
            chunks = GifImagePlugin.getdata(image, duration=self.duration)
        else:
            chunks = self._delta(indices)
        for chunk in chunks:
            self.handle.write(chunk)
        self._previous = indices
        self.frames += 1

    def _delta(self, indices: np.ndarray) -> list[bytes]:
        """A frame after the first: the rectangle that changed, its unchanged pixels transparent
        (long runs of one index, which LZW compresses to a tenth of the size)."""
        from PIL import GifImagePlugin, Image

        assert self._previous is not None
        changed = np.argwhere(indices != self._previous)
        top, left = changed.min(axis=0) if len(changed) else (0, 0)
        bottom, right = changed.max(axis=0) + 1 if len(changed) else (1, 1)
        window = (slice(int(top), int(bottom)), slice(int(left), int(right)))
        rectangle = indices[window].copy()
        rectangle[rectangle == self._previous[window]] = TRANSPARENT
        image = Image.frombytes("P", rectangle.shape[::-1], rectangle.tobytes())
        image.putpalette(self._palette.getpalette())
        offset = (int(left), int(top))
        return GifImagePlugin.getdata(image, offset=offset, duration=self.duration, transparency=TRANSPARENT)

    def finish(self) -> None:
        """Write the GIF trailer (after at least one frame)."""
        if self.frames == 0:
            raise ValueError("a GIF needs at least one frame")
        self.handle.write(b";")


@contextmanager
def gif_writer(
    path: str | Path, fps: int = 8, palette_sample: np.ndarray | None = None
) -> Iterator[GifWriter]:
    """A :class:`GifWriter` on a temporary file beside ``path``, renamed to ``path`` when the block
    ends; if the block fails, ``path`` is left as it was and the temporary file is removed."""
    with atomic_path(path) as temporary, temporary.open("wb") as handle:
        writer = GifWriter(handle, fps=fps, palette_sample=palette_sample)
        yield writer
        writer.finish()


def episode_colors(env: Any) -> np.ndarray:
    """A frame of ``env``'s graph with its targets spread over every level of uncertainty
    (0 to ``u_max``), drawn by a renderer of its own: the colours an episode's frames can hold."""
    from sb3_pm.envs.rendering import GraphRenderer

    base = env.unwrapped
    graph, u_max = base.graph, base.u_max
    renderer = GraphRenderer(graph, u_max)
    try:
        uncertainty = np.zeros(graph.n_nodes, dtype=int)
        uncertainty[graph.targets] = np.linspace(0, u_max, graph.n_targets).round().astype(int)
        return renderer.draw(uncertainty, np.flatnonzero(graph.targets)[:1], 0)
    finally:
        renderer.close()


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
    threads: int | None = 1,
) -> EpisodeRecord:
    """Play one episode (env seed ``seed``, as episode 0 of ``evaluate(seed=seed)``) and save it,
    each frame written as it is drawn (:class:`GifWriter`; ``path`` is replaced at the end only).

    :param threads: torch CPU threads while the team acts, as in
        :func:`~sb3_pm.evaluation.evaluate` (one by default: a small forward pass is several times
        slower on two threads beside another process); ``None`` leaves torch's count.

    ``graph``, ``n_agents`` and ``env_kwargs`` mean what they mean for
    :func:`~sb3_pm.evaluation.evaluate`: a trained team acts on its own graph, with its own size and
    in its own env settings unless told otherwise.

    :param deterministic: passed to ``team.predict_dict``, as in :func:`~sb3_pm.evaluation.evaluate`
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
    try:
        with torch_threads(threads), gif_writer(path, fps=fps, palette_sample=episode_colors(env)) as writer:
            return run_episode(
                team, env, seed, frames=writer, deterministic=team.acts_deterministically(deterministic)
            )
    finally:
        env.close()


def write_gif(frames: Sequence[np.ndarray], path: str | Path, fps: int = 8) -> Path:
    """Write ``(H, W, 3)`` uint8 frames as a looping GIF with one palette for every frame, taken
    from a sample of the frames (:class:`GifWriter`; ``path`` is replaced atomically)."""
    if len(frames) == 0:
        raise ValueError("write_gif needs at least one frame")
    sample = np.concatenate(list(frames[:: max(1, len(frames) // 8)]), axis=0)
    with gif_writer(path, fps=fps, palette_sample=sample) as writer:
        for frame in frames:
            writer.append(frame)
    return Path(path)
