"""Deploying a trained team on a graph it was not trained on (zero-shot transfer).

A DCBF policy is nearly independent of the graph's size ``N``: the GAT layers have per-node
weights, the estimator and the actor are MLPs shared across nodes (one logit per node) and the
critic mean-pools. Two things tie it to ``N``:

* the paper's Laplacian-rows encoding (``laplacian: rows``), ``N`` numbers per node, which fixes
  the first GAT layer's input width; ``laplacian: none`` does not;
* the observation space (``N`` nodes) SB3 checks observations against.

Choice (measured in research/LOG.md, "Transfer"): the observation spaces are **rebuilt** for the new
graph rather than padded to a maximum size with a node mask. Rebuilding keeps every tensor at its
true size (no cost on small graphs, no cap on large ones), and each learner's policy is rebuilt
with the same constructor arguments on the new spaces and given the trained parameters. The only
size-dependent tensors a transferable policy holds are the input scalings ``inv_high`` ``(N, F)``
(F node features), whose rows are all equal (one scale per feature, from ``u_max`` and the
training episode length); they are rebuilt row by row from the trained ones, so inputs are
scaled exactly as in training.

Mental maps start anew on the new graph (a new env), as on any first episode: empty, or with the
new graph's static map when the team's env settings make it known (``target_knowledge``,
``graph_knowledge``).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import torch as th

from sb3_pm.agents.deployment.rule import DeploymentRule
from sb3_pm.agents.deployment.saved_teams import check_same_graph
from sb3_pm.errors import InputError
from sb3_pm.graphs import GraphLike, GraphSpec, resolve_graph
from sb3_pm.policies.dcbf import SITE_BOUND
from sb3_pm.team_interface import Team

#: Buffers whose first dimension is the node count and whose rows are identical.
_PER_NODE_BUFFERS = ("inv_high",)


def transfer_problem(team: Any) -> str | None:
    """Why ``team`` cannot act on another graph, or ``None`` if it can."""
    for agent in team.agents:
        policy = team.models[agent].policy
        encoder = getattr(policy, "_encoder_kwargs", None)
        if encoder is None:
            return (
                f"{agent}'s policy ({type(policy).__name__}) reads fixed-size flattened observations; "
                "only the DCBF policy (algo dcbf_ppo) transfers"
            )
        if encoder["laplacian"] == "rows":
            return (
                f"{agent}'s encoder uses the Laplacian-rows encoding (laplacian: rows), N numbers per "
                f"node, which ties its first GAT layer to N = {policy.n_nodes}; train it with "
                "policy_kwargs laplacian: none to deploy on other graphs"
            )
    return None


def rebuild_policy(policy: Any, observation_space: Any, action_space: Any) -> Any:
    """``policy``'s class and arguments on new spaces, holding ``policy``'s trained parameters.

    :raises InputError: if a parameter's shape depends on the graph's size.
    """
    arguments = policy._get_constructor_parameters()
    arguments.update(observation_space=observation_space, action_space=action_space)
    rebuilt = type(policy)(**arguments)
    n_nodes = int(observation_space["nodes"].shape[0])
    state = {}
    for key, value in policy.state_dict().items():
        if key.rsplit(".", 1)[-1] in _PER_NODE_BUFFERS:
            value = value[:1].expand(n_nodes, *value.shape[1:]).clone()  # one scale per feature
        state[key] = value
    target = rebuilt.state_dict()
    mismatched = [key for key, value in state.items() if key in target and target[key].shape != value.shape]
    if mismatched:
        raise InputError(f"the policy's parameters {mismatched} depend on the graph's size")
    rebuilt.load_state_dict(state)
    rebuilt.set_training_mode(False)
    if hasattr(policy, "sampling_temperature"):  # a deployment setting, not a constructor argument
        rebuilt.sampling_temperature = policy.sampling_temperature
    return rebuilt.to(policy.device)


def policy_territories(policies: Mapping[str, Any], graph: GraphSpec) -> dict[str, tuple[int, ...]]:
    """``{name: its territory on graph}``: learner ``i`` of ``K`` (``policies`` in the team's agent
    order) takes the ``i``-th territory of ``graph``'s ``K``-way split, as on its own graph."""
    from sb3_pm.graphs.territories import agent_territories

    return dict(zip(policies, agent_territories(graph, len(policies))))


def retarget_territories(policies: dict[str, Any], graph: GraphSpec) -> None:
    """Give each rebuilt policy whose neglect bound has scope ``territory`` its territory on ``graph``
    (:func:`policy_territories`).

    The bound names its territory's nodes on the graph it was set for, which mean nothing on
    another graph.
    """
    from dataclasses import replace

    def scoped(policy: Any) -> bool:
        config = getattr(policy, "dcbf_config", None)
        return config is not None and config.neglect_bound is not None and config.neglect_scope == "territory"

    if not any(scoped(policy) for policy in policies.values()):
        return
    for name, territory in policy_territories(policies, graph).items():
        if scoped(policies[name]):
            policies[name].dcbf_config = replace(policies[name].dcbf_config, territory=territory)


class TransferredTeam(DeploymentRule):
    """A trained team's policies rebuilt for another graph; acts like the team it came from.

    :ivar source: the trained team (its graph, agents and settings).
    :ivar graph: the graph it now runs on.
    """

    omniscient = False
    resizable = True

    def __init__(self, source: Any, graph: GraphSpec, layout: str | None = None) -> None:
        from sb3_pm.envs import persistent_monitoring_v0

        self.source, self.graph = source, graph
        self.name = f"{getattr(source, 'name', 'team')} on {graph.name}"
        self.n_agents, self.algo = source.n_agents, source.algo
        self.env_kwargs = dict(source.env_kwargs)
        if layout is not None:  # the observations' layout is the env's: the spaces follow it
            self.env_kwargs["layout"] = layout
        self.agents = list(source.agents)
        # The spaces of the new graph with the training env's settings (u_max, episode length),
        # so observations are checked and scaled as the team was trained.
        env = persistent_monitoring_v0.parallel_env(graph=graph, n_agents=self.n_agents, **self.env_kwargs)
        space, action = env.observation_space(self.agents[0]), env.action_space(self.agents[0])
        env.close()
        self.policies = {
            agent: rebuild_policy(source.models[agent].policy, space, action) for agent in self.agents
        }
        retarget_territories(self.policies, graph)
        # the rebuilt policies act as the source's do: its settings are theirs until changed here
        self.__dict__["_filter_settings"] = source.filter_settings
        #: how the team acts by default, as the source team's (rebuild_policy kept its temperature)
        self._deploy_temperature = getattr(source, "deploy_temperature", None)
        if (getattr(source, "deploy_filter", None) or {}).get("neglect_bound") == SITE_BOUND:
            # A bound calibrated on the source's graph says nothing of this one: none until this
            # site is calibrated (evaluate() does it before the first episode).
            self.await_site_bound()

    def acting_policies(self) -> dict[str, Any]:
        """``{agent: policy}``: the rebuilt policies (:class:`DeploymentRule`)."""
        return self.policies

    def _filter_territories(self) -> dict[str, tuple[int, ...]]:
        """``{agent: its territory}`` on the graph the team was moved to
        (:meth:`DeploymentRule.set_filter`)."""
        return policy_territories(self.policies, self.graph)

    def policy_for(self, agent: str) -> Any:
        """The rebuilt policy of the learner that acts for ``agent``."""
        return self.policies[self.learner_for(agent)]

    def learner_for(self, agent: str) -> str:
        """The learner acting for ``agent`` (see :meth:`IndependentPPO.learner_for`)."""
        return str(self.source.learner_for(agent))

    def reset(self, env: Any, seed: int | None = None) -> None:
        super().reset(env, seed)
        self._warn_if_site_bound_pending()
        self._episode_territories()
        other = getattr(getattr(env, "unwrapped", env), "graph", None)
        if isinstance(other, GraphSpec):
            try:
                check_same_graph(self.graph, other)
            except InputError as error:
                rebuilt = f"it was rebuilt for graph {self.graph.name!r}: use on_graph()"
                raise InputError(f"{error}; {rebuilt}") from error
        if seed is not None:
            th.manual_seed(seed)


def on_graph(team: Any, graph: GraphLike, layout: str | None = None) -> Team:
    """``team`` itself on its own graph, else its policies rebuilt for ``graph``.

    :param layout: the env's observation layout to act in (``"dense"`` or ``"edges"``,
        :mod:`sb3_pm.envs.known_edges`); ``None``: the team's own. Another layout than the team's
        rebuilds its policies on that layout's spaces, on its own graph too.
    :raises InputError: a team that cannot transfer, with the reason (:func:`transfer_problem`).
    """
    spec = resolve_graph(graph)
    own_layout = team.env_kwargs.get("layout", "dense")
    if spec.fingerprint == team.graph.fingerprint:
        if layout is None or layout == own_layout:
            return team  # type: ignore[no-any-return]
        return TransferredTeam(team, spec, layout)  # same size: nothing ties it to the layout
    problem = transfer_problem(team)
    if problem is not None:
        raise InputError(
            f"the team was trained on graph {team.graph.name!r} and cannot act on graph "
            f"{spec.name!r}: {problem}"
        )
    return TransferredTeam(team, spec, layout)


__all__ = ["TransferredTeam", "on_graph", "policy_territories", "rebuild_policy", "transfer_problem"]
