"""A checkpoint's state beyond the saved team, as plain values: ``state.json`` and ``state.npz``.

A checkpoint holds a saved team (:mod:`sb3_pm.agents.deployment.saved_teams`), which gives the
learners' parameters, optimizer states and step counts, and this state, which the team needs to go
on bit for bit from the rollout barrier:

* the multiplexer's: every env copy, the running episode returns and lengths, the last observations
  and the learners' random streams (:class:`~sb3_pm.agents.multiplexing.hub_state.HubState`);
* each learner's rollout state, which a saved team does not restore (it starts further training
  with an env reset): :func:`learner_state_dict` / :func:`load_learner_state`.

Both are written with :mod:`sb3_pm.plain_state`: JSON, and arrays read with ``allow_pickle=False``.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from sb3_pm.errors import InputError
from sb3_pm.plain_state import read_state, write_state

if TYPE_CHECKING:
    from sb3_pm.agents.training.team import IndependentPPO

#: The files of a checkpoint's state: the JSON tree and its arrays.
STATE_JSON = "state.json"
STATE_ARRAYS = "state.npz"


def learner_state_dict(model: Any) -> dict[str, Any]:
    """An SB3 learner's rollout state: the observation it acts on next, which of its env copies
    start an episode, and its episode-info buffers (what it logs)."""
    return {
        "last_obs": model._last_obs,
        "last_episode_starts": model._last_episode_starts,
        "last_original_obs": model._last_original_obs,
        "ep_info_buffer": model.ep_info_buffer,
        "ep_success_buffer": model.ep_success_buffer,
    }


def load_learner_state(model: Any, state: dict[str, Any]) -> None:
    """Put back a :func:`learner_state_dict` into a learner loaded from the same checkpoint.

    :raises InputError: if a key is missing.
    """
    try:
        model._last_obs = state["last_obs"]
        model._last_episode_starts = state["last_episode_starts"]
        model._last_original_obs = state["last_original_obs"]
        model.ep_info_buffer = state["ep_info_buffer"]
        model.ep_success_buffer = state["ep_success_buffer"]
    except (KeyError, TypeError) as error:
        raise InputError(f"the saved learner state is incomplete or malformed ({error!r})") from None


def write_team_state(team: IndependentPPO, folder: Path) -> None:
    """Write the team's checkpoint state (multiplexer and learners) to ``folder``."""
    state = {
        "hub": team.hub.state_dict(),
        "learners": {agent: learner_state_dict(team.models[agent]) for agent in team.agents},
    }
    write_state(state, folder / STATE_JSON, folder / STATE_ARRAYS)


def read_team_state(team: IndependentPPO, folder: Path) -> None:
    """Put the checkpoint state in ``folder`` into ``team``, loaded from the same checkpoint.

    :raises InputError: if the files are malformed or do not fit the team.
    """
    state = read_state(folder / STATE_JSON, folder / STATE_ARRAYS)
    if not isinstance(state, dict) or not isinstance(state.get("learners"), dict):
        raise InputError("the checkpoint state is not a team's")
    learners = state["learners"]
    if sorted(learners) != sorted(team.agents):
        raise InputError(f"the checkpoint state is for agents {sorted(learners)}, not {team.agents}")
    streams = team.hub.load_state_dict(state.get("hub"))
    for agent in team.agents:
        load_learner_state(team.models[agent], learners[agent])
    team._resume_streams = streams


__all__ = [
    "STATE_ARRAYS",
    "STATE_JSON",
    "learner_state_dict",
    "load_learner_state",
    "read_team_state",
    "write_team_state",
]
