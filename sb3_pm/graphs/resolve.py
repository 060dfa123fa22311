"""Turn a user-facing graph string (a preset name or a ``.graphml`` path) into a :class:`GraphSpec`.

The environment, the CLI and the YAML configs all go through :func:`resolve_graph`, so the three
accept exactly the same strings.
"""

from __future__ import annotations

from pathlib import Path

from sb3_pm.graphs.distributions import GraphFamily, is_family_name, resolve_family
from sb3_pm.graphs.io import load_graphml
from sb3_pm.graphs.presets import PRESETS, preset
from sb3_pm.graphs.spec import GraphError, GraphSpec

GraphLike = str | Path | GraphSpec


def resolve_graph(graph: GraphLike) -> GraphSpec:
    """Return ``graph`` itself if it is a spec, a preset by name, or the GraphML file at a path.

    :raises GraphError: for a string that is neither a preset nor a ``.graphml`` path.
    :raises FileNotFoundError: for a ``.graphml`` path that does not exist.
    """
    if isinstance(graph, GraphSpec):
        return graph
    text = str(graph)
    if text in PRESETS:
        return preset(text)
    if text.lower().endswith((".graphml", ".xml")) or isinstance(graph, Path):
        return load_graphml(text)
    if is_family_name(text):
        raise GraphError(
            f"{text!r} is a graph family, which only training takes (sb3-pm train --env); "
            "evaluate on a graph: a preset or a .graphml path"
        )
    raise GraphError(
        f"unknown graph {text!r}: use a preset ({', '.join(sorted(PRESETS))}) or a .graphml path"
    )


def resolve_graph_or_family(graph: GraphLike | GraphFamily) -> GraphSpec | GraphFamily:
    """:func:`resolve_graph`, or a graph family for ``family:...`` values and
    :class:`~sb3_pm.graphs.distributions.GraphFamily` objects (what training accepts)."""
    if isinstance(graph, GraphFamily) or (isinstance(graph, str) and is_family_name(graph)):
        return resolve_family(graph)
    return resolve_graph(graph)


def graph_label(graph: GraphLike | GraphFamily) -> str:
    """A short name for reports and folders: the preset name, the file's stem, or ``family-NAME``."""
    if isinstance(graph, (GraphSpec, GraphFamily)):
        return graph.name.replace(":", "-").replace("/", "-")
    text = str(graph)
    if is_family_name(text):
        return "family-" + Path(text.split(":", 1)[1]).name
    return text if text in PRESETS else Path(text).stem
