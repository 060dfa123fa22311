""":class:`DeploymentRule`: how a trained team acts, kept in one place, and its only ``predict_dict``.

Every trained team reaches it: :class:`~sb3_pm.agents.training.team.IndependentPPO` (one learner per
agent), :class:`~sb3_pm.sharing.centralized.CentralizedPPO` (one shared network) and a trained team
moved to another graph (:class:`~sb3_pm.agents.deployment.transfer.TransferredTeam`). They differ only in
where their policies live (:meth:`DeploymentRule.policy_for`, :meth:`DeploymentRule.acting_policies`)
and which graph gives their territories (:meth:`DeploymentRule._filter_territories`).

The acting rule is three values, held here and nowhere else:

* :attr:`DeploymentRule.deploy_temperature`: argmax (``None``) or a sampling temperature;
* :attr:`DeploymentRule.filter_settings`: the DCBF filter settings the team acts under on top of
  what each policy was trained with (``neglect_bound``, ``neglect_scope``, ...); each policy's
  ``dcbf_config`` is derived from its trained config and these, never saved in its kwargs;
* :attr:`DeploymentRule.site_bound_pending`: a ``deploy_filter`` of ``auto`` waiting for the bound
  calibrated on the graph it acts on.

A saved team's manifest records them (:mod:`sb3_pm.agents.deployment.saved_teams`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import fields, replace
from typing import Any

import numpy as np

from sb3_pm.agents.deployment.visit_memory import group_visit_rows, start_visit_memory, step_visit_memory
from sb3_pm.errors import InputError
from sb3_pm.planning.conventions import is_planned
from sb3_pm.team_interface import Observation, Team, without_caller_keys


class DeploymentRule(Team):
    """The acting rule of a trained team (temperature, DCBF filter, pending calibration), its
    environment settings and its one :meth:`predict_dict` (SB3's shape around it:
    :meth:`~sb3_pm.team_interface.Team.predict`)."""

    learned = True
    _deploy_temperature: float | None = None
    #: the learners' algorithm (in error messages)
    algo: str
    #: the env settings the team was trained in (``env_kwargs`` of its config)
    env_kwargs: dict[str, Any]
    #: the graph the team acts on, or the family it was trained on
    graph: Any
    #: whether :meth:`_warn_if_site_bound_pending` has warned (once per team)
    _warned_pending: bool = False
    #: Act for the whole team in one pass over the policies' stacked parameters where they allow
    #: it (:mod:`sb3_pm.agents.deployment.team_forward`; the same actions, bit for bit);
    #: ``False`` runs one pass per agent.
    stacked_inference: bool = True
    #: One network acts for every agent: its observations go through it as one batch.
    shares_one_network: bool = False
    #: the team's forward pass, made on first use (:meth:`_forward_pass`)
    _team_forward: Any = None

    # ------------------------------------------------------------ the env
    def env_settings(self) -> dict[str, Any]:
        """The env settings the team was trained in, less the caller's keys (graph, team size,
        episode length, render mode): a trained team is evaluated in the env it was trained in."""
        return without_caller_keys(self.env_kwargs)

    def default_graph(self) -> Any:
        """The graph the team acts on (``None`` for a team trained on a graph family)."""
        from sb3_pm.graphs import GraphSpec

        return self.graph if isinstance(self.graph, GraphSpec) else None

    # ------------------------------------------------------------ acting
    def policy_for(self, agent: str) -> Any:
        """The policy that acts for ``agent``."""
        raise NotImplementedError

    def acting_policies(self) -> Mapping[str, Any]:
        """``{name: policy}``: every policy that acts for the team."""
        raise NotImplementedError

    def predict_dict(  # type: ignore[override]
        self, observations: dict[str, Observation], deterministic: bool | None = None
    ) -> dict[str, int]:
        """One destination node per agent in ``observations``, each from its own policy
        (:meth:`policy_for`). ``deterministic=None`` follows :attr:`deploy_temperature` (argmax
        unless the config set one); ``False`` samples at :attr:`sampling_temperature`.

        Policies of one architecture act in one pass for the whole team, their own forward mapped
        over their stacked parameters (:mod:`sb3_pm.agents.deployment.team_forward`, the same
        actions as one pass per agent, bit for bit); sampled actions are drawn agent by agent, in
        the team's order.
        """
        deterministic = self.acts_deterministically(deterministic)
        step_visit_memory(self, observations)  # rule 12's memory: this step's positions
        agents = list(observations)
        if self.stacked_inference and not self.shares_one_network:
            policies = [self.policy_for(agent) for agent in agents]
            batch = [observations[agent] for agent in agents]
            together = self._forward_pass().actions(policies, batch, deterministic)
            if together is not None:
                return {agent: int(action) for agent, action in zip(agents, together)}
        if not self.shares_one_network:
            grouped = _grouped_actions(
                [self.policy_for(agent) for agent in agents],
                [observations[agent] for agent in agents],
                deterministic,
            )
            if grouped is not None:
                return dict(zip(agents, grouped))
        groups = [agents] if self.shares_one_network else [[agent] for agent in agents]
        actions: dict[str, int] = {}
        for group in groups:
            group_visit_rows(self, group)
            batch = [observations[agent] for agent in group]
            actions.update(zip(group, _policy_actions(self.policy_for(group[0]), batch, deterministic)))
        return actions

    def reset(self, env: Any, seed: int | None = None) -> None:
        """Start an episode on ``env`` (already reset), and the memory of the filter's rule 12
        where the team acts under it (:mod:`sb3_pm.agents.deployment.visit_memory`)."""
        super().reset(env, seed)
        self.__dict__["_visit_memory"] = start_visit_memory(self, env)

    def _forward_pass(self) -> Any:
        """The team's forward pass (:class:`~sb3_pm.agents.deployment.team_forward.TeamForward`),
        made on first use: it keeps the stacked parameters between steps."""
        if self._team_forward is None:
            from sb3_pm.agents.deployment.team_forward import TeamForward

            self._team_forward = TeamForward()
        return self._team_forward

    def acting_record(self, deterministic: bool) -> dict[str, Any]:
        """The sampling temperature (when sampling), the neglect bound the team acts under,
        ``leave_cleared`` / ``pass_held`` / ``keep_moving: True`` where its policies act under the
        filter's rule 9 / 10 / 11, and rule 12's ``visit_deadline``."""
        from sb3_pm.policies.dcbf import FILTER_SWITCHES

        record: dict[str, Any] = {}
        if not deterministic and self.sampling_temperature is not None:
            record["temperature"] = self.sampling_temperature
        bound = self.acting_filter()
        if bound is not None:
            record.update(bound)
        configs = [getattr(policy, "dcbf_config", None) for policy in self.acting_policies().values()]
        for switch in FILTER_SWITCHES:
            if any(config is not None and getattr(config, switch) for config in configs):
                record[switch] = True
        deadlines = {config.visit_deadline for config in configs if config is not None} - {None}
        if deadlines:
            record["visit_deadline"] = max(deadlines)
        return record

    # ------------------------------------------------ the pending site bound
    def await_site_bound(self) -> None:
        """No bound until a site is calibrated: the policies act with none, and
        :attr:`site_bound_pending` says a calibration is due (``deploy_filter`` auto on a team built,
        loaded or moved, or whose calibrated deployment failed).

        :raises InputError: a policy without the DCBF filter, which could never take the bound.
        """
        self.set_filter(neglect_bound=None)
        self.site_bound_pending = True

    def _warn_if_site_bound_pending(self) -> None:
        """Say once that a team with ``deploy_filter`` auto acts with no bound on a graph it was
        not calibrated on (an episode started without :func:`sb3_pm.evaluation.evaluate`)."""
        if self.site_bound_pending and not self._warned_pending:
            import warnings

            warnings.warn(
                "deploy_filter auto: no neglect bound has been calibrated for this graph, so the team "
                "acts with none; evaluate() calibrates it first, or call "
                "sb3_pm.evaluation.neglect_calibration.settle_site_bound(team, graph, n_agents, env_kwargs, "
                "max_cycles), or set one with team.set_filter(neglect_bound=B or None)",
                stacklevel=3,
            )
            self._warned_pending = True

    # ------------------------------------------------------- temperature
    @property
    def deploy_temperature(self) -> float | None:  # type: ignore[override]
        """How the team acts when nothing says otherwise (``predict(obs)``, ``predict_dict(obs)``,
        ``evaluate()``, ``sb3-pm evaluate`` and ``compare``): ``None`` takes each agent's most likely
        allowed node (argmax); a temperature samples from ``softmax(logits / T)`` over the allowed
        nodes, as :meth:`set_sampling_temperature`. Set by the config's ``deploy_temperature`` and saved with
        the team. Training never reads it.

        :raises InputError: on setting anything but ``None`` or a positive finite number.
        """
        return self._deploy_temperature

    @deploy_temperature.setter
    def deploy_temperature(self, temperature: float | None) -> None:
        from sb3_pm.policies.sampling import check_deploy_temperature

        value = check_deploy_temperature(temperature)
        self._apply_deploy_temperature(value)  # first: a team it cannot apply to keeps its rule
        self._deploy_temperature = value

    def _apply_deploy_temperature(self, temperature: float | None) -> None:
        """Give the policies the deployment temperature (1, the trained distribution, under argmax).

        :raises InputError: a temperature for a policy that is not a DCBF policy.
        """
        if temperature is not None or self.sampling_temperature not in (None, 1.0):
            self.set_sampling_temperature(1.0 if temperature is None else temperature)

    @property
    def sampling_temperature(self) -> float | None:
        """The temperature sampled actions are drawn at (:meth:`set_sampling_temperature`): the
        policies' common value, ``None`` if they differ or have none (not DCBF policies)."""
        values = {getattr(policy, "sampling_temperature", None) for policy in self.acting_policies().values()}
        return values.pop() if len(values) == 1 else None

    def set_sampling_temperature(self, temperature: float) -> None:
        """Sampled actions (``predict_dict(..., deterministic=False)``) of every policy come from
        ``softmax(logits / temperature)`` over its allowed nodes, for deployment; deterministic
        actions are unchanged. Not saved with the team (:attr:`deploy_temperature` is).

        :raises InputError: a temperature that is not a positive finite number, or a policy that is
            not a DCBF policy.
        """
        from sb3_pm.policies.sampling import set_sampling_temperature

        set_sampling_temperature(self.acting_policies(), temperature)

    # ------------------------------------------------------ the DCBF filter
    @property
    def filter_settings(self) -> dict[str, Any]:
        """The DCBF filter settings the team acts under on top of its policies' trained ones
        (:meth:`set_filter`); ``{}``: as trained. Saved with the team."""
        return dict(self.__dict__.get("_filter_settings", {}))

    def acting_filter(self) -> dict[str, Any] | None:
        """The DCBF neglect bound the policies act under now, ``{"neglect_bound": B,
        "neglect_scope": S}`` (the first bounded policy's), or ``None`` if no policy has one."""
        for policy in self.acting_policies().values():
            config = getattr(policy, "dcbf_config", None)
            if config is not None and config.neglect_bound is not None:
                return {"neglect_bound": config.neglect_bound, "neglect_scope": config.neglect_scope}
        return None

    def set_filter(self, **changes: Any) -> None:
        """Change the DCBF filter's settings of every acting policy (fields of
        :class:`~sb3_pm.policies.dcbf.DCBFConfig`, e.g. ``neglect_bound=40``), for deployment.

        The filter has no parameters, so a trained team can be deployed with another filter (the
        actor then meets masks it was not trained under), on its own graph or on one it was moved
        to. ``neglect_scope="territory"`` gives each policy its own agent's territory on the graph
        the team acts on (:mod:`sb3_pm.graphs.territories`, :meth:`_filter_territories`). The
        settings are kept in :attr:`filter_settings` and saved with the team.

        :raises InputError: a policy without the DCBF filter, or an unknown or invalid setting; no
            policy changes then.
        """
        from sb3_pm.policies.dcbf import ADVICE_SWITCHES, SITE_BOUND, DCBFConfig, check_bound_below_cap

        names = {f.name for f in fields(DCBFConfig)}
        unknown = sorted(set(changes) - names)
        if unknown:
            raise InputError(f"unknown DCBF filter setting(s) {unknown}; known: {sorted(names)}")
        bound = changes.get("neglect_bound")
        if bound is not None and (isinstance(bound, bool) or not isinstance(bound, (int, float))):
            raise InputError(f"neglect_bound must be a number (or None), got {bound!r}")
        if "territory" in changes:
            raise InputError("territory is set by neglect_scope='territory', from the team's graph")
        for switch in ADVICE_SWITCHES:
            if changes.get(switch) and self.env_settings().get("advice_input") is not True:
                raise InputError(
                    f"{switch} (a filter rule) reads the advised node: the team needs env_kwargs "
                    "advice_input: true, which its env settings do not have"
                )
        policies = self.acting_policies()
        for name, policy in policies.items():  # every check before any policy changes
            if not getattr(policy, "use_dcbf", False):
                raise InputError(f"{name} has no DCBF filter to change (algo {self.algo}, use_dcbf off)")
            check_bound_below_cap(bound, getattr(policy, "u_max", float("inf")))
        settings = {**self.filter_settings, **changes}
        # visit_deadline auto is a number per site, given at calibration (visit_memory.settle_deadline)
        acting = (
            {**settings, "visit_deadline": None} if settings.get("visit_deadline") == SITE_BOUND else settings
        )
        territories = self._bound_territories() if settings.get("neglect_scope") == "territory" else {}
        # Every new config first: DCBFConfig checks its fields as it is built, so a bad setting
        # raises here, before any policy has changed.
        configs = {
            name: replace(
                policy.trained_dcbf_config,
                **acting,
                **({"territory": territories[name]} if territories else {}),
            )
            for name, policy in policies.items()
        }
        if "neglect_bound" in changes:
            self.site_bound_pending = False  # the bound is settled for this graph
        for name, policy in policies.items():
            policy.dcbf_config = configs[name]
            policy.avoid_collisions = configs[name].avoid_collisions
        self.__dict__["_filter_settings"] = settings

    def reset_filter(self) -> None:
        """Every policy back to the filter it was trained with (:attr:`filter_settings` empty)."""
        for policy in self.acting_policies().values():
            if getattr(policy, "use_dcbf", False):
                policy.dcbf_config = policy.trained_dcbf_config
                policy.avoid_collisions = policy.trained_dcbf_config.avoid_collisions
        self.__dict__["_filter_settings"] = {}

    def filter_activity(self) -> dict[str, int]:
        """Summed over the acting policies since they were built: masks computed with the neglect
        bound on (``masks``) and masks it forced (``forced``); see
        :class:`~sb3_pm.policies.policy.DCBFActorCriticPolicy`."""
        total = {"masks": 0, "forced": 0}
        for policy in self.acting_policies().values():
            for key, value in getattr(policy, "filter_counts", {}).items():
                total[key] = total.get(key, 0) + int(value)  # int() of a tensor count: one sync here
        return total

    def _filter_territories(self) -> dict[str, tuple[int, ...]]:
        """``{policy name: the target nodes of its agent's territory}`` on the graph the team acts on.

        :raises InputError: where the team has no territories (one per agent, on one graph).
        """
        raise NotImplementedError

    def _plays_planned_territories(self) -> bool:
        """Whether the team's territories are planned per episode (``territories: planned`` or
        ``planned_tours``): in the env it was last reset on, else in its own env settings."""
        env = getattr(getattr(self, "env", None), "unwrapped", None)
        if env is not None:
            convention = getattr(env, "territories", None)
        else:
            convention = self.env_kwargs.get("territories")
        return convention is not None and is_planned(convention)

    def _bound_territories(self) -> dict[str, tuple[int, ...]]:
        """``{policy name: the targets its neglect bound of scope territory guards}``: the split
        (:meth:`_filter_territories`), or under planned territories each agent's planned group of
        the episode the team was last reset on (all empty before the first reset, since the groups
        depend on the episode's start positions). Learners shared by more agents than there are
        policies keep the split here; :meth:`_episode_territories` refuses them.
        """
        names = list(self.acting_policies())
        territory = self._planned_groups()
        if not self._plays_planned_territories() or (territory is not None and len(territory) != len(names)):
            return self._filter_territories()
        if territory is None:
            return {name: () for name in names}
        return {name: tuple(int(node) for node in np.flatnonzero(row)) for name, row in zip(names, territory)}

    def _planned_groups(self) -> Any:
        """``(n_agents, N)`` bool, the planned groups of the env the team was last reset on, or
        ``None`` (no env yet, or one without territories)."""
        return getattr(getattr(getattr(self, "env", None), "unwrapped", None), "_territory", None)

    def _episode_territories(self) -> None:
        """Under planned territories and a neglect bound of scope ``territory``, point each
        policy's bound at its agent's group for the episode just reset (the groups follow the
        start positions, so a bound set once would guard another episode's territory)."""
        settings = self.filter_settings
        if settings.get("neglect_scope") != "territory" or settings.get("neglect_bound") is None:
            return
        if not self._plays_planned_territories():
            return
        policies, groups = self.acting_policies(), self._planned_groups()
        if groups is not None and len(groups) != len(policies):
            raise InputError(
                f"a territory neglect bound in an env that plans territories needs one learner per "
                f"agent; {len(policies)} learners act for {len(groups)} agents here: "
                "set_filter(neglect_bound=None) or neglect_scope 'known'"
            )
        for name, territory in self._bound_territories().items():
            policies[name].dcbf_config = replace(policies[name].dcbf_config, territory=territory)


def _grouped_actions(
    policies: Sequence[Any], observations: Sequence[Observation], deterministic: bool
) -> list[int] | None:
    """The actions of ``policies[k]`` on ``observations[k]`` for every ``k``, as one pass per agent
    decides them, from one forward pass per distinct policy on all of its agents' maps; ``None``
    (one pass per agent) unless the maps are in the env's edges layout and every policy is a DCBF
    policy.

    The edges layout is where the team's stacked pass (:mod:`.team_forward`) declines: a 5,000-node
    site's 64 agents share four learners, and 64 passes of one map each cost 16 times the
    per-pass overhead of four passes of 16 maps. Each agent's action is still decided on its own
    row, in the team's order (sampled ones drawn one row at a time, as one pass per agent draws
    them), and rule 8's decisions are counted per policy as its own pass counts them. On a large
    site the logits come from the allowed nodes' neighbourhoods (:mod:`sb3_pm.policies.local_pass`:
    the same up to rounding).
    """
    import torch as th

    from sb3_pm.policies import local_pass
    from sb3_pm.policies.edges import is_edge_layout
    from sb3_pm.policies.heads import masked_mode

    if not observations or not all(hasattr(policy, "draw") for policy in policies):
        return None
    if not all(isinstance(obs, Mapping) and is_edge_layout(obs) for obs in observations):
        return None
    rows: dict[int, list[int]] = {}  # id(policy) -> the agents it acts for, in the team's order
    for k, policy in enumerate(policies):
        rows.setdefault(id(policy), []).append(k)
    decided: dict[int, tuple[th.Tensor, th.Tensor, int]] = {}  # agent -> (logits, masks, its row)
    for members in rows.values():
        policy = policies[members[0]]
        keys = observations[members[0]]
        batch = {key: np.stack([np.asarray(observations[k][key]) for k in members]) for key in keys}
        policy.set_training_mode(False)  # as SB3's predict does
        tensors, _ = policy.obs_to_tensor(batch)
        with th.no_grad():
            pre = policy._preprocess(tensors)
            u_hat = policy.uncertainty(pre)
            masks = policy._masks(pre, u_hat, np.asarray(batch["action_mask"], dtype=bool))
            if local_pass.applies(policy, pre):  # a large site: the allowed nodes' neighbourhoods
                logits = local_pass.allowed_logits(policy, pre, u_hat, masks)
            else:
                logits = policy._logits(pre, u_hat, masks)
        for row, k in enumerate(members):
            decided[k] = (logits, masks, row)
    actions = []
    with th.no_grad():
        for k, policy in enumerate(policies):  # the team's order: sampled draws as one pass per agent
            logits, masks, row = decided[k]
            one = (logits[row : row + 1], masks[row : row + 1])
            chosen = masked_mode(*one) if deterministic else policy.draw(*one)
            actions.append(int(chosen.reshape(-1)[0]))
    return actions


def _policy_actions(policy: Any, observations: Sequence[Observation], deterministic: bool) -> list[int]:
    """``policy``'s actions for a batch of observations (its own forward pass and masks)."""
    from sb3_contrib.common.maskable.policies import MaskableActorCriticPolicy

    batch = {key: np.stack([np.asarray(obs[key]) for obs in observations]) for key in observations[0]}
    if isinstance(policy, MaskableActorCriticPolicy):
        actions, _ = policy.predict(
            batch, deterministic=deterministic, action_masks=np.asarray(batch["action_mask"], dtype=bool)
        )
    else:
        actions, _ = policy.predict(batch, deterministic=deterministic)
    return [int(action) for action in np.asarray(actions).reshape(-1)]


__all__ = ["DeploymentRule"]
