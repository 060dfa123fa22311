"""The actor and critic heads of the DCBF policy, on the graph encoder's node embeddings.

:class:`ActorCriticHeads` is a part of :class:`~sb3_pm.policies.policy.DCBFActorCriticPolicy` (its
first base class): it turns a batch of ``B`` preprocessed maps on ``N`` nodes, with the estimate
``û`` ``(B, N)``, into one logit per node and a value per map (docs/METHOD.md "Network of one
agent"). The actor is one MLP applied to every node with shared weights, input
``[H_m, û_m / u_max, H_φ]``; the critic is an MLP on ``[mean_m [H_m, û_m / u_max], H_φ]``. It reads
the policy's ``features_extractor``, ``actor_body``, ``action_net``, ``critic_body``,
``value_net``, ``use_estimator``, ``u_max`` and ``advice_prior``.
"""

from __future__ import annotations

from itertools import islice
from typing import Any

import torch as th
from torch import nn

from sb3_pm.policies.edges import is_large_site
from sb3_pm.policies.extractor import GATFeaturesExtractor


def own_positions(pre: dict[str, th.Tensor]) -> th.Tensor:
    """``(B,)`` each preprocessed map's own node (its index, or the argmax of its one-hot)."""
    return pre["position_index"] if "position_index" in pre else pre["position"].argmax(-1)


def masked_mode(logits: th.Tensor, masks: th.Tensor) -> th.Tensor:
    """The mode of sb3-contrib's masked categorical distribution, computed the way it computes it.

    ``MaskableCategorical`` normalizes the logits, sets masked entries to -1e8, normalizes again,
    takes the softmax and its argmax. Doing exactly those operations keeps every tie and rounding
    identical (``tests/test_policy.py`` compares the two).

    Shapes:
        - logits: ``(B, N)`` float; masks: ``(B, N)`` bool, no row all False
        - output: ``(B,)`` long
    """
    normalized = logits - logits.logsumexp(dim=-1, keepdim=True)
    masked = th.where(masks, normalized, th.tensor(-1e8, dtype=logits.dtype, device=logits.device))
    masked = masked - masked.logsumexp(dim=-1, keepdim=True)
    return th.argmax(th.softmax(masked, dim=-1), dim=1)


class ActorCriticHeads:
    """The heads' computations (see the module docstring)."""

    features_extractor: Any
    actor_body: nn.Sequential
    action_net: nn.Linear
    critic_body: nn.Sequential
    value_net: nn.Linear
    use_estimator: bool
    u_max: float
    advice_prior: float

    def _node_inputs(self, pre: dict[str, th.Tensor], u_hat: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        """The heads' inputs: per-node ``[H_m, û_m / u_max]`` ``(B, N, d)`` and the agent's own
        node's embedding ``(B, h)``."""
        extractor: GATFeaturesExtractor = self.features_extractor  # type: ignore[assignment]
        return self._with_estimate(extractor.node_embeddings(pre), pre, u_hat)

    def _with_estimate(
        self, embeddings: th.Tensor, pre: dict[str, th.Tensor], u_hat: th.Tensor
    ) -> tuple[th.Tensor, th.Tensor]:
        """``[H_m, û_m / u_max]`` ``(B, N, d)`` and the own node's ``H_φ`` ``(B, h)`` from the
        embeddings ``H`` ``(B, N, h)``."""
        batch = embeddings.shape[0]
        position = own_positions(pre)
        own = embeddings[th.arange(batch, device=embeddings.device), position]  # (B, h)
        if self.use_estimator:
            embeddings = th.cat((embeddings, (u_hat / self.u_max).unsqueeze(-1)), dim=-1)
        return embeddings, own

    def _heads(
        self, pre: dict[str, th.Tensor], u_hat: th.Tensor, masks: th.Tensor
    ) -> tuple[th.Tensor, th.Tensor]:
        """Per-node logits ``(B, N)`` (see :meth:`_actor_logits`) and values ``(B, 1)``.

        On a large site's edges-layout maps (:meth:`_large_site_heads`) the actor runs on the nodes
        ``masks`` allows alone, and the other logits are 0: the masked distribution never reads
        them, and their gradient is 0 either way."""
        extractor: GATFeaturesExtractor = self.features_extractor  # type: ignore[assignment]
        if is_large_site(pre, extractor.n_nodes):
            return self._large_site_heads(pre, u_hat, masks)
        embeddings, own = self._node_inputs(pre, u_hat)
        logits = self._with_advice(self._actor_logits(embeddings, own), pre)
        return logits, self._value(embeddings, own)

    def _large_site_heads(
        self, pre: dict[str, th.Tensor], u_hat: th.Tensor, masks: th.Tensor
    ) -> tuple[th.Tensor, th.Tensor]:
        """:meth:`_heads` computed where it is read: the actor on the allowed nodes (on a
        1,000-node site about five of a thousand per map, where its activations on every node were
        a third of an update's memory), and the critic on the mean of the node inputs taken column
        by column, without the ``(B, N, d)`` copy that joins ``û`` to the embeddings. The same
        function, rounded otherwise (products on fewer rows, means over other layouts).

        Shapes: pre's maps ``(B, N, ...)``, u_hat ``(B, N)``, masks ``(B, N)`` bool -> logits
        ``(B, N)`` (0 where masked), values ``(B, 1)``.
        """
        extractor: GATFeaturesExtractor = self.features_extractor  # type: ignore[assignment]
        embeddings = extractor.node_embeddings(pre)  # (B, N, h)
        batch, n, width = embeddings.shape
        own = embeddings[th.arange(batch, device=embeddings.device), own_positions(pre)]  # (B, h)
        rows = masks.reshape(-1).nonzero().squeeze(-1)  # (R,) allowed nodes, as indices of B * N
        logits = self._allowed_logits(embeddings.reshape(-1, width)[rows], own, u_hat, rows, pre)
        means = [embeddings.mean(1)]  # (B, h)
        if self.use_estimator:
            means.append((u_hat / self.u_max).mean(1, keepdim=True))
        return logits, self.value_net(self.critic_body(th.cat((*means, own), dim=-1)))

    def _allowed_logits(
        self,
        embedded: th.Tensor,
        own: th.Tensor,
        u_hat: th.Tensor,
        rows: th.Tensor,
        pre: dict[str, th.Tensor],
    ) -> th.Tensor:
        """The actor's logits, with the advice, on the allowed nodes ``rows`` alone, 0 elsewhere:
        the last step of :meth:`_large_site_heads` and of acting from the allowed nodes'
        neighbourhoods (:func:`sb3_pm.policies.local_pass.allowed_logits`).

        Shapes: embedded ``(R, h)`` (the rows' embeddings), own ``(B, h)``, u_hat ``(B, N)``, rows
        ``(R,)`` indices of ``B * N`` -> ``(B, N)``.
        """
        batch, n = u_hat.shape
        of_map = rows // n  # (R,) each row's map
        if self.use_estimator:
            embedded = th.cat((embedded, (u_hat.reshape(-1)[rows] / self.u_max).unsqueeze(-1)), dim=-1)
        own_term = None  # an actor without a hidden layer has no separate product with own
        if len(self.actor_body) and isinstance(self.actor_body[0], nn.Linear):
            own_term = self._actor_own_term(own)[of_map]  # (R, w)
        hidden = self._actor_hidden(embedded.unsqueeze(1), own[of_map], own_term=own_term)  # (R, 1, w')
        logits = th.zeros(batch * n, dtype=hidden.dtype, device=hidden.device)
        logits[rows] = self._actor_output(hidden).reshape(-1)
        return self._with_advice(logits.reshape(batch, n), pre)

    def _value(self, embeddings: th.Tensor, own: th.Tensor) -> th.Tensor:
        """The critic on ``[mean_m embeddings_m, own]``: ``(B, N, d)``, ``(B, h)`` -> ``(B, 1)``."""
        return self.value_net(self.critic_body(th.cat((embeddings.mean(1), own), dim=-1)))

    def _logits(self, pre: dict[str, th.Tensor], u_hat: th.Tensor, masks: th.Tensor) -> th.Tensor:
        """Per-node logits ``(B, N)`` alone: acting needs no critic."""
        embeddings, own = self._node_inputs(pre, u_hat)
        return self._with_advice(self._actor_logits(embeddings, own), pre)

    def _with_advice(self, logits: th.Tensor, pre: dict[str, th.Tensor]) -> th.Tensor:
        """The logits ``(B, N)`` plus ``advice_prior`` on the node the env's ``advice_input``
        column (the map's last) flags: the territory rule's move starts out as the likely one, and
        the actor learns where to leave it. A fixed input, not a parameter."""
        if not self.advice_prior:
            return logits
        return logits + self.advice_prior * pre["nodes"][..., -1]

    def _actor_logits(self, embeddings: th.Tensor, own: th.Tensor) -> th.Tensor:
        """One logit per node: ``(B, N, d)``, ``(B, h)`` -> ``(B, N)``."""
        return self._actor_output(self._actor_hidden(embeddings, own))

    def _actor_output(self, hidden: th.Tensor) -> th.Tensor:
        """The one-unit output layer on the actor body's ``(B, N, pi_out)``: logits ``(B, N)``. A
        matrix-vector product: a team's pass over stacked parameters
        (:mod:`sb3_pm.agents.deployment.team_forward`) runs it policy by policy, to round as alone."""
        return self.action_net(hidden).squeeze(-1)  # type: ignore[no-any-return]

    def _actor_own_term(self, own: th.Tensor) -> th.Tensor:
        """The actor's first-layer product with the own node's embedding, ``(B, h) -> (B, w)``
        (:meth:`_actor_hidden`), with one row per map it runs as a matrix-vector product: a team's
        pass over stacked parameters (:mod:`sb3_pm.agents.deployment.team_forward`) computes it
        policy by policy, to round as this policy does alone."""
        first: nn.Linear = self.actor_body[0]  # type: ignore[assignment]
        return nn.functional.linear(own, first.weight[:, first.weight.shape[1] - own.shape[-1] :])

    def _actor_hidden(
        self, embeddings: th.Tensor, own: th.Tensor, own_term: th.Tensor | None = None
    ) -> th.Tensor:
        """The actor body on ``[embeddings_m, own]`` for every node ``m`` given.

        The first layer's product with ``own`` is the same for every node of a map, so it is computed
        once per map and broadcast instead of multiplying ``N`` copies (same function and parameters
        as ``actor_body(cat(embeddings, own expanded))``; a third of the actor's first-layer work).

        Shapes:
            - embeddings: ``(B, N, d)``; own: ``(B, h)``; own_term: :meth:`_actor_own_term`
              ``(B, w)`` if computed already
            - output: ``(B, N, pi_out)``
        """
        first = self.actor_body[0] if len(self.actor_body) else None
        if not isinstance(first, nn.Linear):  # no hidden layer: plain concatenation
            own_per_node = own.unsqueeze(1).expand(-1, embeddings.shape[1], -1)
            return self.actor_body(th.cat((embeddings, own_per_node), dim=-1))
        width = embeddings.shape[-1]
        per_node = nn.functional.linear(embeddings, first.weight[:, :width], first.bias)  # (..., w)
        per_map = self._actor_own_term(own) if own_term is None else own_term  # (B, w)
        hidden = per_node + per_map.unsqueeze(1)
        # The remaining layers one by one: slicing the Sequential (actor_body[1:]) would build a new
        # module on every call, a tenth of a millisecond per rollout step.
        for layer in islice(self.actor_body, 1, None):
            hidden = layer(hidden)
        return hidden


__all__ = ["ActorCriticHeads", "masked_mode", "own_positions"]
