"""One forward pass per rollout step for all of a team's learners.

While a team collects its rollouts, every learner runs its own policy's forward pass on its own
observation, one learner after the other (:mod:`sb3_pm.agents.multiplexing.multiplexer`'s baton): ``K`` small
passes per joint step, each a few hundred tensor operations on ``n_envs`` maps, where the time goes
to per-operation overhead rather than arithmetic. Every learner's observation for the next step is
known as soon as the joint step is published, so the first learner to act can compute all ``K``
passes as one :class:`~sb3_pm.agents.deployment.team_forward.TeamForward` pass (each policy's own code with
its own parameters, on its own maps) and leave the others their results.

Nothing is shared but the arithmetic, and nothing changes in what is computed:

* the team pass gives each policy's logits, values and DCBF masks equal to its own
  ``rollout_heads`` bit for bit (``tests/test_team_forward.py``);
* each learner still draws its action from torch's generator itself, in its own turn, so every
  draw comes from its own random stream, in the order it always did, and rule 8's decisions are
  counted in a learner's ``filter_counts`` when it takes its result, as its own pass counts them;
* a learner is served only for the very observation object the multiplexer handed it (its
  ``_last_obs``), and only if its parameters and filter settings are those the pass used: a
  callback that changes a policy in place during a rollout (``on_step``) makes that learner run
  its own pass. A write through ``.data``, which torch's version counters do not see, is not
  detected: a callback that writes a policy's parameters that way should run with
  ``IndependentPPO.batched_rollouts = False``.

So a seeded run trains the same parameters, bit for bit, with batching on or off
(``tests/test_rollout_batching.py``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import torch as th

from sb3_pm.agents.deployment.team_forward import RolloutHeads, TeamForward
from sb3_pm.agents.multiplexing.multiplexer import ParallelEnvMultiplexer

Heads = tuple[th.Tensor, th.Tensor, th.Tensor]


class RolloutBatcher:
    """Serves each learner of a team its rollout step's ``(logits, values, masks)`` from one
    team pass per joint step.

    :param hub: the team's multiplexer (its :attr:`~ParallelEnvMultiplexer.published`
        observations are the passes' inputs).
    :param models: the learners, in the hub's agent order, each a
        :class:`~sb3_pm.ppo_dcbf.DCBFPPO` (``rollout_heads_source`` is what :meth:`attach` sets).
    """

    def __init__(self, hub: ParallelEnvMultiplexer, models: Sequence[Any]) -> None:
        if len(models) != hub.n_agents:
            raise ValueError(f"{len(models)} learners for a hub of {hub.n_agents} agents")
        self.hub = hub
        self.models = list(models)
        self.team_forward = TeamForward()
        # Each learner's parameter objects, found once: their version counters tell whether a
        # policy changed between the team pass and the learner's turn.
        self._parameters = [list(model.policy.parameters()) for model in self.models]
        self._inputs: list[dict[str, Any]] | None = None  # the observation objects of the last step
        self._outputs: list[RolloutHeads] | None = None  # its results (None: it was refused)
        self._versions: list[tuple[int, ...]] = []
        self._configs: list[Any] = []
        #: joint steps served by one team pass, and learner passes left to their own forward
        self.counts = {"stacked": 0, "serial": 0}
        #: why the last step that was not stacked was not (``None``: every step so far was)
        self.refusal: str | None = None

    def attach(self) -> None:
        """Route every learner's rollout passes through this batcher."""
        for index, model in enumerate(self.models):
            model.rollout_heads_source = self.source(index)

    def detach(self) -> None:
        """Give every learner its own forward pass back."""
        for model in self.models:
            model.rollout_heads_source = None

    def source(self, index: int) -> Callable[[Any], Heads | None]:
        """The ``rollout_heads_source`` of learner ``index``."""
        return lambda observation: self.heads(index, observation)

    def heads(self, index: int, observation: Any) -> Heads | None:
        """Learner ``index``'s ``(logits, values, masks)`` on ``observation``, counting its rule-8
        decisions, or ``None`` when it must run its own pass.

        Shapes: logits ``(n_envs, N)``, values ``(n_envs, 1)``, masks ``(n_envs, N)`` bool.
        """
        if self._inputs is None or self._inputs[index] is not observation:
            self._compute(index, observation)  # afterwards: this observation's results, or None
        outputs = self._outputs
        policy = self.models[index].policy
        if (
            outputs is None
            or self._versions[index] != _versions(self._parameters[index])
            or policy.dcbf_config is not self._configs[index]
        ):
            if outputs is not None:
                self.refusal = "a learner's policy changed during the rollout step"
            self.counts["serial"] += 1
            return None
        served = outputs[index]
        if served.forced is not None:
            policy.count_forced(served.forced)
        return served.logits, served.values, served.masks

    def _compute(self, index: int, observation: Any) -> None:
        """One team pass on every learner's published observation (learner ``index`` must be
        acting on its own), or a refusal remembered for this step."""
        published = [obs for obs in self.hub.published if isinstance(obs, dict)]  # Dict spaces only
        if len(published) != len(self.models) or published[index] is not observation:
            self._inputs, self._outputs = None, None
            self.refusal = "the observation is not the one the multiplexer published"
            return
        policies = [model.policy for model in self.models]
        self._versions = [_versions(parameters) for parameters in self._parameters]
        self._configs = [policy.dcbf_config for policy in policies]
        self._inputs = published
        self._outputs = self.team_forward.rollout_heads(policies, published)
        if self._outputs is not None:
            self.counts["stacked"] += 1
        else:  # the learners of this step run their own passes; nobody computes it again
            self.refusal = self.team_forward.refusal


def _versions(parameters: Sequence[th.Tensor]) -> tuple[int, ...]:
    """Torch's version counters of ``parameters`` (each in-place write bumps its tensor's)."""
    return tuple(p._version for p in parameters)


__all__ = ["RolloutBatcher"]
