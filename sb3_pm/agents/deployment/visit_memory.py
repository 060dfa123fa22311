"""The deployed team's memory for the filter's rule 12, the visit deadline
(:mod:`sb3_pm.policies.visit_deadline`): each agent's visit set and the steps since it last stood
on each node.

The memory is each agent's own: where it has stood, which it knows without any message. The team
keeps one row per agent (:class:`VisitMemory`), starts it at every reset
(:func:`start_visit_memory`) and, before each step, gives every policy its agent's row
(:meth:`VisitMemory.give`). One call of the team per env step, as ``evaluate()`` and a
PettingZoo loop make: each call counts as a step.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from typing import Any

import numpy as np
import torch as th

from sb3_pm.baselines.rule_neglect import site_deadline
from sb3_pm.errors import InputError
from sb3_pm.planning.conventions import sweep_targets
from sb3_pm.policies.dcbf import SITE_BOUND
from sb3_pm.policies.visit_deadline import SWEPT


class VisitMemory:
    """Each agent's visit set and steps since it last stood on each node.

    :param agents: the agents in the env's order.
    :param visit_targets: ``(n_agents, N)`` int, each agent's visit set: 1 on its territory,
        :data:`~sb3_pm.policies.visit_deadline.SWEPT` on the targets it sweeps, 0 elsewhere.
    """

    def __init__(self, agents: list[str], visit_targets: np.ndarray) -> None:
        self.rows = {agent: row for row, agent in enumerate(agents)}
        self.visit_targets = th.as_tensor(np.asarray(visit_targets, dtype=np.int8))
        #: ``(n_agents, N)`` float: steps since the agent stood on each node (since the reset if never).
        self.since = th.zeros(self.visit_targets.shape, dtype=th.float32)
        self._steps = 0

    def observe(self, positions: Mapping[str, int]) -> None:
        """One step: every count grows by one (but at the reset's observation), then each agent's
        own node goes back to 0."""
        if self._steps:
            self.since += 1
        self._steps += 1
        rows = [self.rows[agent] for agent in positions]
        self.since[rows, list(positions.values())] = 0

    def give(self, team: Any, observations: Mapping[str, Mapping[str, Any]]) -> None:
        """Observe the agents' positions in ``observations`` and give each policy the rows of the
        agents it acts for, in the order of ``observations`` (``policy.visit_inputs``, each
        ``(k, N)``): the order every pass of the team reads its maps in."""
        self.observe(
            {agent: int(np.asarray(obs["position"]).reshape(-1)[0]) for agent, obs in observations.items()}
        )
        rows: dict[int, tuple[Any, list[int]]] = {}
        for agent in observations:
            policy = team.policy_for(agent)
            rows.setdefault(id(policy), (policy, []))[1].append(self.rows[agent])
        for policy, own in rows.values():
            policy.visit_inputs = (self.visit_targets[own], self.since[own])

    def rows_of(self, agents: list[str]) -> tuple[th.Tensor, th.Tensor]:
        """The visit sets and counts of ``agents``, in that order, each ``(len(agents), N)``."""
        own = [self.rows[agent] for agent in agents]
        return self.visit_targets[own], self.since[own]


def start_visit_memory(team: Any, env: Any) -> VisitMemory | None:
    """The memory for an episode of ``env`` (just reset), or ``None`` where the team acts without
    rule 12. The visit sets are the territories the team's neglect bound would guard (the split, or
    the episode's planned groups) with the swept targets added.

    ``visit_deadline: auto`` takes its number for the site, team size, episode length and
    territory convention here, from :func:`~sb3_pm.baselines.rule_neglect.site_deadline`, with the
    team's env settings and the env's own convention (which ``--territories`` may have set; once
    per site; none where every calibrated rule left a target unvisited for a whole episode).

    :raises InputError: where no territory per agent can be found.
    """
    if team.filter_settings.get("visit_deadline") is None:
        return None
    base = getattr(env, "unwrapped", env)
    agents = list(base.possible_agents)
    if team.filter_settings["visit_deadline"] == SITE_BOUND:  # calibrated once per site
        key = site_key(base.graph, len(agents), base.max_cycles, base.territories)
        known = team.__dict__.get("_site_deadline")
        if known is None or known[0] != key:
            settings = {**team.env_settings(), "territories": base.territories}  # the env's, not training's
            known = (key, site_deadline(base.graph, len(agents), settings, base.max_cycles))
        settle_deadline(team, *known)
        if known[1] is None:  # every rule left a target unvisited all episode: no deadline here
            return None
    graph = base.graph
    territory = team._planned_groups()  # the env's own rows, one per agent, where it keeps them
    if territory is None or len(territory) != len(agents):
        territory = _split_by_policy(team, agents, graph.n_nodes)
    swept = sweep_targets(territory, graph.target_indices, graph.routes, base.positions)
    return VisitMemory(agents, np.where(swept, SWEPT, np.asarray(territory, dtype=bool)))


def _split_by_policy(team: Any, agents: list[str], n_nodes: int) -> np.ndarray:
    """``(n_agents, N)`` bool: each agent's territory by its policy's (one learner per agent).

    :raises InputError: where learners are shared (a policy's territory is then not one agent's).
    """
    policies = [team.policy_for(agent) for agent in agents]
    if len({id(policy) for policy in policies}) != len(agents):
        raise InputError(
            "the filter's visit_deadline (rule 12) needs each agent's territory: an env with "
            "territory_input or advice_input gives them, or one learner per agent; "
            f"{len({id(p) for p in policies})} learners act for {len(agents)} agents here"
        )
    territories = team._bound_territories()
    by_policy = {id(policy): territories[name] for name, policy in team.acting_policies().items()}
    territory = np.zeros((len(agents), n_nodes), dtype=bool)
    for row, policy in enumerate(policies):
        territory[row, list(by_policy[id(policy)])] = True
    return territory


def site_key(graph: Any, n_agents: int, max_cycles: int, territories: str) -> tuple[str, int, int, str]:
    """What a calibrated ``visit_deadline: auto`` was calibrated for: the site, team size, episode
    length and territory convention (which rules calibrate it)."""
    return (str(graph.fingerprint), int(n_agents), int(max_cycles), str(territories))


def settle_deadline(team: Any, key: tuple[str, int, int, str], deadline: int | None) -> None:
    """Give every acting policy of a team with ``visit_deadline: auto`` the deadline calibrated
    for site ``key``, or none (its :attr:`filter_settings` keep ``auto``, for the next site)."""
    team.__dict__["_site_deadline"] = (key, deadline)
    for policy in team.acting_policies().values():
        policy.dcbf_config = replace(policy.dcbf_config, visit_deadline=deadline)


def step_visit_memory(team: Any, observations: Mapping[str, Mapping[str, Any]]) -> None:
    """Give the team's memory (:func:`start_visit_memory`, kept by its ``reset``) this step's
    positions and each policy its row; nothing where the team acts without rule 12.

    :raises InputError: rule 12 set after the episode began (its counts start at the reset).
    """
    memory = team.__dict__.get("_visit_memory")
    if memory is not None:
        memory.give(team, observations)
        return
    if team.filter_settings.get("visit_deadline") is None:  # every team without rule 12, every step
        return
    acting = (getattr(p, "dcbf_config", None) for p in team.acting_policies().values())
    if any(c is not None and c.visit_deadline is not None for c in acting):
        raise InputError(
            "the filter's visit_deadline (rule 12) counts steps from the episode's start: reset the "
            "team on the env (team.reset(env)) after setting it"
        )


def group_visit_rows(team: Any, group: list[str]) -> None:
    """Before one pass of the team for the agents of ``group`` (one policy): that policy reads
    their rows of the memory, in that order (nothing where the team acts without rule 12)."""
    memory = team.__dict__.get("_visit_memory")
    if memory is not None:
        team.policy_for(group[0]).visit_inputs = memory.rows_of(group)


__all__ = [
    "VisitMemory",
    "group_visit_rows",
    "settle_deadline",
    "site_key",
    "start_visit_memory",
    "step_visit_memory",
]
