""":class:`DeploymentRule`: how a trained team acts when the caller does not say.

Shared by the trained teams (:class:`~sb3_pm.agents.learned_team.LearnedTeam`) and a trained team
moved to another graph (:class:`~sb3_pm.agents.transfer.TransferredTeam`), which differ only in
where their policies live (:meth:`DeploymentRule.acting_policies`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any


class DeploymentRule:
    """The ``deploy_temperature`` rule and the sampling temperature of a team's DCBF policies."""

    _deploy_temperature: float | None = None

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


__all__ = ["DeploymentRule"]
