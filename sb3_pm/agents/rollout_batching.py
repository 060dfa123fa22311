"""One stacked forward pass per rollout step for all of a team's learners.

While a team collects its rollouts, every learner runs its own policy's forward pass on its own
observation, one learner after the other (:mod:`sb3_pm.agents.multiplexer`'s baton): ``K`` small
passes per joint step, each about 150 tensor operations on ``n_envs`` maps, where the time goes to
per-operation overhead rather than arithmetic. Every learner's observation for the next step is
known as soon as the joint step is published, so the first learner to act can compute all ``K``
passes as one :class:`~sb3_pm.agents.stacked_inference.StackedInference` pass (each policy with
its own parameters, on its own maps) and leave the others their results.

Nothing is shared but the arithmetic, and nothing changes in what is computed:

* the stacked pass gives each policy's logits, values and DCBF masks equal to its own
  ``rollout_heads`` bit for bit, and checks that it does where it runs (else every step runs
  serially, as before);
* each learner still draws its action from torch's generator itself, in its own turn, so every
  draw comes from its own random stream, in the order it always did;
* a learner is served only for the very observation object the multiplexer handed it (its
  ``_last_obs``); anything else (a wrapper, an observation it changed) runs its own pass.

So a seeded run trains the same parameters, bit for bit, with batching on or off
(``tests/test_rollout_batching.py``). The learners' parameters change only in their update
phases, which end at the rollout barrier before any pass of the next rollout.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import torch as th

from sb3_pm.agents.multiplexer import ParallelEnvMultiplexer
from sb3_pm.agents.stacked_inference import StackedInference

Heads = tuple[th.Tensor, th.Tensor, th.Tensor]


class RolloutBatcher:
    """Serves each learner of a team its rollout step's ``(logits, values, masks)`` from one
    stacked pass per joint step.

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
        self.stacker = StackedInference()
        self._inputs: list[dict[str, Any]] | None = None  # the observation objects of the last pass
        self._outputs: list[Heads] = []
        #: joint steps served by one stacked pass, and learner passes left to their own forward
        self.counts = {"stacked": 0, "serial": 0}

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

    @property
    def problem(self) -> str | None:
        """Why the learners' passes are not stacked (``None``: they are, or none was asked yet)."""
        return self.stacker._problem

    def heads(self, index: int, observation: Any) -> Heads | None:
        """Learner ``index``'s ``(logits, values, masks)`` on ``observation``, or ``None`` when it
        must run its own pass.

        Shapes: logits ``(n_envs, N)``, values ``(n_envs, 1)``, masks ``(n_envs, N)`` bool.
        """
        inputs = self._inputs
        if inputs is None or inputs[index] is not observation:
            published = [obs for obs in self.hub.published if isinstance(obs, dict)]  # Dict spaces only
            if len(published) != len(self.models) or published[index] is not observation:
                self.counts["serial"] += 1
                return None
            outputs = self.stacker.rollout_heads([model.policy for model in self.models], published)
            if outputs is None:
                self._inputs = None
                self.counts["serial"] += 1
                return None
            self._inputs, self._outputs = published, outputs
            self.counts["stacked"] += 1
        return self._outputs[index]


__all__ = ["RolloutBatcher"]
