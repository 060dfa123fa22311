"""Turning a ``--policy`` string into a team: a baseline name or a saved trained team directory."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from sb3_pm.baselines import BASELINES, make_team
from sb3_pm.errors import InputError
from sb3_pm.graphs import resolve_graph
from sb3_pm.pretrained import PREFIX, pretrained_names, pretrained_path
from sb3_pm.team_interface import Team


class PolicyError(InputError):
    """A ``--policy`` that names no baseline and no loadable trained team."""


def resolve_team(
    policy: str | Path, graph: Any = None, device: str = "cpu", layout: str | None = None, **kwargs: Any
) -> Team:
    """A team for ``policy``.

    :param policy: a baseline name (a key of :data:`~sb3_pm.baselines.BASELINES`), a shipped
        trained team (``pretrained:paper-50``, :mod:`sb3_pm.pretrained`) or the path of a
        directory holding a saved trained team (loaded with ``IndependentPPO.load``).
    :param graph: for a trained team, the graph it will run on; its loader checks that the team
        was trained on the same problem. Ignored for baselines.
    :param device: torch device of a trained team (``cpu``, ``cuda``, ``auto``); ignored for baselines.
    :param layout: for a trained team, the env's observation layout it will act in (``"dense"``,
        ``"edges"``; ``None``: its own): its policies are rebuilt for another one. A baseline reads
        either; the env's ``layout`` setting is the caller's.
    :param kwargs: constructor arguments for a baseline; ignored for a trained team.
    :raises PolicyError: an unknown name, or a directory that cannot be loaded.
    :raises FileNotFoundError: a path-like policy that does not exist.
    """
    text = str(policy)
    if text in BASELINES:
        return make_team(text, **kwargs)
    if text.startswith(PREFIX):  # a team that ships with the package
        return load_trained_team(pretrained_path(text), graph, device=device, layout=layout)
    path = Path(text).expanduser()
    if path.is_dir():
        return load_trained_team(path, graph, device=device, layout=layout)
    if path.exists():
        raise PolicyError(f"policy {text!r} is a file; a trained team is a directory written by its save()")
    if "/" in text or "\\" in text or text.startswith("."):
        raise FileNotFoundError(f"trained team directory not found: {text}")
    raise PolicyError(
        f"unknown policy {text!r}: use a baseline ({', '.join(BASELINES)}), a pretrained team "
        f"({', '.join(PREFIX + name for name in pretrained_names())}) or a trained team directory"
    )


def load_trained_team(
    path: str | Path, graph: Any = None, device: str = "cpu", layout: str | None = None
) -> Team:
    """``IndependentPPO.load(path)`` (or ``CentralizedPPO.load`` for a centralized team's folder),
    imported lazily so that baselines never need torch; ``layout``: as :func:`resolve_team`'s."""
    path = Path(path)
    try:
        from sb3_pm.agents.training.team import IndependentPPO
        from sb3_pm.sharing.centralized import MANIFEST_FORMAT as CENTRALIZED
        from sb3_pm.sharing.centralized import OLD_FORMATS as OLD_CENTRALIZED
        from sb3_pm.sharing.centralized import CentralizedPPO
    except ImportError as error:
        raise PolicyError(
            f"cannot load the trained team in {path}: "
            f"sb3_pm.agents.training.team.IndependentPPO is unavailable ({error})"
        ) from error
    # The manifest's ``format`` field says which team type wrote it (a run folder of
    # ``sb3-pm train`` keeps the team in ``team/``; the loaders handle both).
    manifest: dict[str, Any] = {}
    for folder in (path, path / "team"):
        if (folder / "manifest.json").exists():
            try:
                from sb3_pm.agents.deployment.saved_teams import read_manifest  # lazy: imports SB3

                manifest = read_manifest(folder)  # every field of the right type
            except (json.JSONDecodeError, TypeError, ValueError) as error:
                message = f"cannot load the trained team in {path}: bad manifest.json ({error})"
                raise PolicyError(message) from error
            break
    centralized = manifest.get("format") in (CENTRALIZED, *OLD_CENTRALIZED)
    team_class: Any = CentralizedPPO if centralized else IndependentPPO
    saved_graph = manifest.get("graph")
    trained_on = saved_graph.get("fingerprint") if isinstance(saved_graph, dict) else None
    other_graph = graph is not None and trained_on not in (None, resolve_graph(graph).fingerprint)
    try:
        if not other_graph:
            own = team_class.load(path, graph=graph, device=device)
            if layout is None or layout == (getattr(own, "env_kwargs", None) or {}).get("layout", "dense"):
                return own  # type: ignore[no-any-return]
            if team_class is CentralizedPPO:
                own.close()
                raise InputError(f"a centralized team acts only in its training layout, not {layout!r}")
            return own.on_graph(own.graph if graph is None else graph, layout)  # type: ignore[no-any-return]
        # Another graph: load the team on its own, then rebuild its policies for this one, or
        # refuse with the reason (sb3_pm.agents.deployment.transfer).
        team = team_class.load(path, device=device)
        try:
            if team_class is CentralizedPPO:
                raise InputError(
                    f"the team was trained on graph {team.graph.name!r}; "
                    "a centralized team cannot act on another graph"
                )
            return team.on_graph(graph, layout)  # type: ignore[no-any-return]
        except BaseException:
            team.close()  # its env copies' workers, before the refusal goes on
            raise
    except (FileNotFoundError, ValueError) as error:
        raise PolicyError(f"cannot load the trained team in {path}: {error}") from error


def policy_label(policy: str | Path, team: Team) -> str:
    """The report label: the baseline's name, the pretrained team's ``pretrained:<name>``, or the
    trained team's directory name."""
    text = str(policy)
    return text if text in BASELINES or text.startswith(PREFIX) else Path(text).name or text
