"""Saved-team files: the folder layout, the manifest, atomic model files and the graph check.

A saved team is a folder::

    team/
      manifest.json     format, graph name + fingerprint, n_agents, env kwargs, algo, policy,
                        hyperparameters (plain JSON, as a config writes them), versions
      <model>.zip ...   SB3 zips (one per agent for IndependentPPO, one shared for CentralizedPPO)
      graph.graphml     only for graphs that are not presets (a team trained on a graph family
                        records the family's parameters in the manifest instead)

Loading runs nothing stored in the folder: the team is rebuilt through its constructor from the
manifest, then each zip gives only its tensors (``torch.load(..., weights_only=True)``) and plain
JSON counters (:mod:`sb3_pm.agents.deployment.model_files`); the zips' pickled entries are never
read. Teams saved in the old formats (``sb3_pm.team/1``, ``sb3_pm.centralized/1``), which could
only be loaded by unpickling, are refused with :class:`OldTeamFormatError`; ``sb3-pm convert-team``
converts one that you trust (:mod:`sb3_pm.agents.training.legacy_teams`).

Every file is written to a temporary name and renamed; the manifest goes last, so a folder with a
manifest holds a whole team.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from sb3_pm.errors import InputError
from sb3_pm.files import write_atomic
from sb3_pm.graphs import (
    PRESETS,
    GraphFamily,
    GraphLike,
    GraphSpec,
    family_from_record,
    resolve_graph,
    save_graphml,
)
from sb3_pm.machine import package_versions

MANIFEST = "manifest.json"


class OldTeamFormatError(InputError):
    """A team saved in an old format, whose loading would unpickle (run) what its files hold."""


def old_format_message(folder: Path, kind: str) -> str:
    """The one line that refuses a team in the old format ``kind`` and says how to convert it."""
    return (
        f"{folder} holds a team in the old format {kind!r}, whose loading can run code stored in its "
        f"files; if you trust them, convert it with 'sb3-pm convert-team {folder} NEW_FOLDER' "
        "(or sb3_pm.convert_team) and load the new folder"
    )


def team_manifest(team: Any, manifest_format: str) -> dict[str, Any]:
    """The manifest fields every saved team kind records (graph, sizes, env, algorithm, versions)."""
    return {
        "format": manifest_format,
        "graph": graph_record(team.graph),
        "n_agents": team.n_agents,
        "env_kwargs": team.env_kwargs,
        "algo": team.algo,
        "policy": team.policy if isinstance(team.policy, str) else team.policy.__name__,
        "n_envs": team.n_envs,
        "seed": team.seed,
        "num_timesteps": team.num_timesteps,
        # how the team acts by default (None: argmax); manifests without it load as None
        "deploy_temperature": team.deploy_temperature,
        # the neglect bound it acts under once trained (None: as trained); older manifests load as None
        "deploy_filter": team.deploy_filter,
        # the DCBF filter settings it acts under on top of the trained ones (a fixed deploy bound,
        # or one set with set_filter); older manifests load as none
        "filter_settings": team.filter_settings,
        "versions": package_versions(),
    }


def graph_record(graph: GraphSpec | GraphFamily) -> dict[str, Any]:
    """How a saved team's manifest names its graph (or the family it was trained on)."""
    if isinstance(graph, GraphFamily):
        return {
            "name": graph.name,
            "fingerprint": graph.fingerprint,
            "n_nodes": graph.max_nodes,
            "family": graph.record(),
        }
    return {
        "name": graph.name,
        "fingerprint": graph.fingerprint,
        "n_nodes": graph.n_nodes,
        "n_targets": graph.n_targets,
    }


def save_graph_copy(graph: GraphSpec | GraphFamily, folder: Path) -> None:
    """Keep a GraphML copy next to a saved team, unless the graph is a preset (rebuilt by name) or
    a family (rebuilt from the manifest's record)."""
    if isinstance(graph, GraphFamily):
        return
    if not (graph.name in PRESETS and resolve_graph(graph.name).same_problem(graph)):
        save_graphml(graph, folder / "graph.graphml", overwrite=True)


def save_model_atomic(model: Any, path: Path) -> None:
    """``model.save`` to a temporary name beside ``path``, then a rename: an interrupted save
    leaves the previous file or the new one, never a truncated zip."""
    temporary = path.with_name(f".{path.stem}.tmp.zip")  # SB3 keeps a .zip suffix as given
    model.save(temporary)
    os.replace(temporary, path)


def write_manifest(folder: Path, manifest: Mapping[str, Any]) -> None:
    """Write ``manifest.json`` atomically (temporary file, then rename)."""
    write_atomic(folder / MANIFEST, json.dumps(manifest, indent=2, sort_keys=True) + "\n")


def read_manifest(folder: Path) -> dict[str, Any]:
    """A saved team's ``manifest.json``.

    :raises FileNotFoundError: if it is missing. :raises ValueError: if it is not valid JSON.
    """
    path = folder / MANIFEST
    if not path.exists():
        raise FileNotFoundError(f"{folder} is not a saved team: {MANIFEST} is missing")
    try:
        manifest = json.loads(path.read_text())
    except json.JSONDecodeError as error:
        raise InputError(f"{path} is not valid JSON: {error}") from error
    check_manifest_fields(path, manifest)
    return dict(manifest)


#: The type of each manifest field the loaders read, and of the ``graph`` record's fields.
MANIFEST_FIELDS: dict[str, tuple[type, ...]] = {
    "graph": (dict,),
    "agents": (list,),
    "n_agents": (int,),
    "n_envs": (int,),
    "seed": (int,),
    "env_kwargs": (dict,),
    "algo": (str,),
    "policy": (str,),
    "format": (str,),
}
GRAPH_FIELDS: dict[str, tuple[type, ...]] = {"name": (str,), "fingerprint": (str,), "family": (dict,)}


def check_manifest_fields(path: Path, manifest: Any) -> None:
    """Refuse a hand-edited or damaged manifest whose fields have the wrong type, with one line
    naming the field, before a loader indexes into it (a ``graph`` written as a string gave a
    ``TypeError`` traceback).

    :raises InputError: naming ``path`` and the field.
    """
    if not isinstance(manifest, dict):
        raise InputError(f"{path}: expected a JSON object, got {type(manifest).__name__}")
    for fields, values, prefix in (
        (MANIFEST_FIELDS, manifest, ""),
        (GRAPH_FIELDS, manifest.get("graph"), "graph."),
    ):
        for name, types in fields.items():
            if not isinstance(values, dict) or name not in values:
                continue
            value = values[name]
            if isinstance(value, bool) or not isinstance(value, types):
                expected = {dict: "an object", list: "a list", int: "an integer", str: "a string"}[types[0]]
                raise InputError(f"{path}: field {prefix}{name} must be {expected}, got {value!r}")


def graph_for_saved_team(
    folder: Path, manifest: Mapping[str, Any], graph: GraphLike | None
) -> GraphSpec | GraphFamily:
    """The graph to run a saved team on: ``graph`` if given, else the saved copy or preset (or, for
    a team trained on a graph family, that family).

    :raises ValueError: if it is not the problem the team was trained on (naming both graphs).
    """
    saved = manifest["graph"]
    if "family" in saved:
        if graph is not None:
            raise InputError(
                f"the team in {folder} was trained on the graph family {saved['name']!r}; load it "
                "without a graph, then deploy it on one with on_graph() (sb3-pm evaluate --graph does)"
            )
        family = family_from_record(saved["family"])
        if family.fingerprint != saved["fingerprint"]:  # e.g. a folder family whose files changed
            raise InputError(
                f"the team in {folder} was trained on the graph family {saved['name']!r} "
                f"(fingerprint {saved['fingerprint']}), which now rebuilds as {family.fingerprint}"
            )
        return family
    if graph is None:
        graph_file = folder / "graph.graphml"
        spec = resolve_graph(graph_file if graph_file.exists() else saved["name"])
    else:
        spec = resolve_graph(graph)
    if spec.fingerprint != saved["fingerprint"]:
        raise InputError(
            f"the team in {folder} was trained on graph {saved['name']!r} "
            f"(fingerprint {saved['fingerprint']}), "
            f"not on graph {spec.name!r} (fingerprint {spec.fingerprint})"
        )
    return spec


def check_same_graph(expected: GraphSpec, actual: GraphSpec) -> None:
    """Raise a ``ValueError`` naming both graphs if they are not the same problem."""
    if expected.fingerprint != actual.fingerprint:
        raise InputError(
            f"the team was trained on graph {expected.name!r} (fingerprint {expected.fingerprint}), "
            f"not on graph {actual.name!r} (fingerprint {actual.fingerprint})"
        )


__all__ = [
    "MANIFEST",
    "check_same_graph",
    "graph_for_saved_team",
    "graph_record",
    "OldTeamFormatError",
    "old_format_message",
    "read_manifest",
    "save_graph_copy",
    "save_model_atomic",
    "team_manifest",
    "write_manifest",
]
