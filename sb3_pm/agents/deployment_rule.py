""":class:`DeploymentRule`: how a trained team acts when the caller does not say, and the DCBF
filter it acts under.

Shared by the trained teams (:class:`~sb3_pm.agents.learned_team.LearnedTeam`) and a trained team
moved to another graph (:class:`~sb3_pm.agents.transfer.TransferredTeam`), which differ in where
their policies live (:meth:`DeploymentRule.acting_policies`), which graph gives their territories
(:meth:`DeploymentRule._filter_territories`) and whether a filter change is saved
(:meth:`DeploymentRule._filter_changed`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any


class DeploymentRule:
    """The ``deploy_temperature`` rule, the sampling temperature and the DCBF filter settings of a
    team's DCBF policies."""

    _deploy_temperature: float | None = None
    #: the learners' algorithm (in error messages)
    algo: str
    #: ``True`` while the team's ``deploy_filter`` is ``{neglect_bound: auto}`` and no bound has been
    #: set for the graph it acts on: :func:`sb3_pm.evaluation.evaluate` then calibrates one there
    #: before the first episode (:mod:`sb3_pm.evaluation.neglect_calibration`). Until then the
    #: policies act with no bound. Any :meth:`set_filter` that sets ``neglect_bound`` (a number, or
    #: ``None`` for none) settles it.
    site_bound_pending: bool = False
    #: whether :meth:`_warn_if_site_bound_pending` has warned (once per team)
    _warned_pending: bool = False

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

    def acting_policies(self) -> Mapping[str, Any]:
        """``{name: policy}``: the policies that act for the team."""
        raise NotImplementedError

    @property
    def deploy_temperature(self) -> float | None:
        """How the team acts when nothing says otherwise (``predict(obs)``, ``evaluate()``,
        ``sb3-pm evaluate`` and ``compare``): ``None`` takes each agent's most likely allowed node
        (argmax); a temperature samples from ``softmax(logits / T)`` over the allowed nodes, as
        :meth:`set_sampling_temperature`. Set by the config's ``deploy_temperature`` and saved with
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

    def acting_filter(self) -> dict[str, Any] | None:
        """The DCBF neglect bound the policies act under now, ``{"neglect_bound": B,
        "neglect_scope": S}`` (the first bounded policy's), or ``None`` if no policy has one."""
        for policy in self.acting_policies().values():
            config = getattr(policy, "dcbf_config", None)
            if config is not None and config.neglect_bound is not None:
                return {"neglect_bound": config.neglect_bound, "neglect_scope": config.neglect_scope}
        return None

    @property
    def sampling_temperature(self) -> float | None:
        """The temperature sampled actions are drawn at (:meth:`set_sampling_temperature`): the
        policies' common value, ``None`` if they differ or have none (not DCBF policies)."""
        values = {getattr(policy, "sampling_temperature", None) for policy in self.acting_policies().values()}
        return values.pop() if len(values) == 1 else None

    def set_sampling_temperature(self, temperature: float) -> None:
        """Sampled actions (``predict(..., deterministic=False)``) of every policy come from
        ``softmax(logits / temperature)`` over its allowed nodes, for deployment; deterministic
        actions are unchanged. Not saved with the team (:attr:`deploy_temperature` is).

        :raises InputError: a temperature that is not a positive finite number, or a policy that is
            not a DCBF policy.
        """
        from sb3_pm.policies.sampling import set_sampling_temperature

        set_sampling_temperature(self.acting_policies(), temperature)

    def set_filter(self, **changes: Any) -> None:
        """Change the DCBF filter's settings of every acting policy (fields of
        :class:`~sb3_pm.policies.dcbf.DCBFConfig`, e.g. ``neglect_bound=40``), for deployment.

        The filter has no parameters, so a trained team can be deployed with another filter (the
        actor then meets masks it was not trained under), on its own graph or on one it was moved
        to. ``neglect_scope="territory"`` gives each policy its own agent's territory on the graph
        the team acts on (:mod:`sb3_pm.graphs.territories`, :meth:`_filter_territories`).

        :raises InputError: a policy without the DCBF filter, or an unknown or invalid setting; no
            policy changes then.
        """
        from dataclasses import fields, replace

        from sb3_pm.errors import InputError
        from sb3_pm.policies.dcbf import DCBFConfig, check_bound_below_cap

        names = {f.name for f in fields(DCBFConfig)}
        unknown = sorted(set(changes) - names)
        if unknown:
            raise InputError(f"unknown DCBF filter setting(s) {unknown}; known: {sorted(names)}")
        bound = changes.get("neglect_bound")
        if bound is not None and (isinstance(bound, bool) or not isinstance(bound, (int, float))):
            raise InputError(f"neglect_bound must be a number (or None), got {bound!r}")
        if "territory" in changes:
            raise InputError("territory is set by neglect_scope='territory', from the team's graph")
        policies = self.acting_policies()
        for name, policy in policies.items():  # every check before any policy changes
            if not getattr(policy, "use_dcbf", False):
                raise InputError(f"{name} has no DCBF filter to change (algo {self.algo}, use_dcbf off)")
            check_bound_below_cap(bound, getattr(policy, "u_max", float("inf")))
        territories = self._filter_territories() if changes.get("neglect_scope") == "territory" else {}
        own = {name: {"territory": territories[name]} if territories else {} for name in policies}
        # Every new config first: DCBFConfig checks its fields as it is built, so a bad setting
        # raises here, before any policy has changed.
        configs = {name: replace(p.dcbf_config, **changes, **own[name]) for name, p in policies.items()}
        if "neglect_bound" in changes:
            self.site_bound_pending = False  # the bound is settled for this graph
        for name, policy in policies.items():
            policy.dcbf_config = configs[name]
            if "avoid_collisions" in changes:
                policy.avoid_collisions = bool(changes["avoid_collisions"])
            self._filter_changed(name, {**changes, **own[name]})

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

    def _filter_changed(self, name: str, changes: Mapping[str, Any]) -> None:
        """Called for each policy whose filter :meth:`set_filter` changed (``changes``: its new
        :class:`~sb3_pm.policies.dcbf.DCBFConfig` fields); a team that saves its policies records
        them here. Nothing by default."""


__all__ = ["DeploymentRule"]
