"""Drawing an episode: a matplotlib picture of the graph (``rgb_array``/``human``) or text (``ansi``)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from sb3_pm.graphs import GraphSpec

if TYPE_CHECKING:
    from sb3_pm.envs.persistent_monitoring import PersistentMonitoringEnv


class GraphRenderer:
    """Draws the graph with targets coloured by uncertainty and agents as numbered markers.

    The static picture (layout, edges, plain nodes, colour bar) is drawn once and kept as a
    background; each frame restores it and redraws only the artists that change (target colours,
    agents, their labels, the title). That is matplotlib's blitting, and it made a 500-frame GIF of
    the 50-node graph several times faster than a full redraw per frame (see the
    ``benchmarks/eval_speed.py`` GIF row). A window (``render_mode="human"``) redraws in full,
    ``blit=False``: its event loop repaints the figure, and a full repaint skips blitted artists.
    """

    def __init__(self, graph: GraphSpec, u_max: int, size_inches: float = 6.0, blit: bool = True) -> None:
        import matplotlib

        matplotlib.use("Agg", force=False)
        import matplotlib.pyplot as plt
        from matplotlib.collections import LineCollection

        self.graph = graph
        self.u_max = u_max
        self.blit = bool(blit)
        self.xy = graph.layout(seed=0)
        self.figure, self.axes = plt.subplots(figsize=(size_inches, size_inches), dpi=80)
        self.axes.set_axis_off()
        rows, cols = np.nonzero(np.triu(graph.adjacency))
        segments = list(np.stack([self.xy[rows], self.xy[cols]], axis=1))
        self.axes.add_collection(LineCollection(segments, colors="0.85", linewidths=0.5, zorder=1))
        others = ~graph.targets
        self.axes.scatter(self.xy[others, 0], self.xy[others, 1], s=12, c="0.6", zorder=2)
        self.targets = self.axes.scatter(
            self.xy[graph.targets, 0],
            self.xy[graph.targets, 1],
            s=90,
            c=np.zeros(graph.n_targets),
            cmap="YlOrRd",
            vmin=0,
            vmax=u_max,
            edgecolors="k",
            zorder=3,
        )
        self.figure.colorbar(self.targets, ax=self.axes, fraction=0.04, label="target uncertainty u")
        self.agents = self.axes.scatter([], [], s=160, marker="^", c="tab:blue", edgecolors="k", zorder=4)
        self.labels: list = []
        self.title = self.axes.set_title("")
        self.background = None
        if self.blit:
            # The changing artists are left out of the full draw, which becomes the background.
            for artist in (self.targets, self.agents, self.title):
                artist.set_animated(True)
            self.figure.canvas.draw()
            self.background = self.figure.canvas.copy_from_bbox(self.figure.bbox)  # type: ignore[attr-defined]

    def draw(self, uncertainty: np.ndarray, positions: np.ndarray, step: int) -> np.ndarray:
        """Return an ``(H, W, 3)`` uint8 frame."""
        self.targets.set_array(uncertainty[self.graph.targets].astype(float))
        self.agents.set_offsets(self.xy[positions])
        for label in self.labels:
            label.remove()
        self.labels = [
            self.axes.annotate(
                str(i),
                self.xy[p],
                ha="center",
                va="center",
                color="w",
                fontsize=7,
                zorder=5,
                animated=self.blit,
            )
            for i, p in enumerate(positions)
        ]
        total = int(uncertainty[self.graph.targets].sum())
        self.title.set_text(f"{self.graph.name}  step {step}  sum of target u = {total}")
        canvas = self.figure.canvas
        if self.blit:
            canvas.restore_region(self.background)  # type: ignore[attr-defined]
            for artist in (self.targets, self.agents, *self.labels, self.title):  # in z order
                self.axes.draw_artist(artist)
        else:
            canvas.draw()
        # Agg canvas (forced above) has buffer_rgba; the base class does not declare it.
        return np.asarray(canvas.buffer_rgba())[:, :, :3].copy()  # type: ignore[attr-defined]

    def show(self) -> None:
        import matplotlib.pyplot as plt

        plt.pause(0.001)

    def close(self) -> None:
        import matplotlib.pyplot as plt

        plt.close(self.figure)


def render_ansi(env: PersistentMonitoringEnv) -> str:
    """One line per target (u and a bar), then agent positions."""
    graph = env.graph
    u = env.core.uncertainty
    lines = [f"step {env.step_count}/{env.max_cycles}  graph {graph.name}"]
    agents_at: dict[int, list[int]] = {}
    for i, p in enumerate(env.core.positions.tolist()):
        agents_at.setdefault(p, []).append(i)
    for node in graph.target_indices.tolist():
        bar = "#" * int(round(20 * u[node] / env.u_max))
        here = ",".join(f"a{i}" for i in agents_at.get(node, []))
        lines.append(f"  target {node:4d}  u={u[node]:3d} {bar:<20s} {here}")
    lines.append("  agents: " + " ".join(f"a{i}@{p}" for i, p in enumerate(env.core.positions.tolist())))
    return "\n".join(lines)
