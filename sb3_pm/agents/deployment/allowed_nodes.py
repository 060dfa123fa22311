"""Most likely actions from the allowed nodes' logits alone, where they decide the same action.

An agent may move only to the nodes its DCBF mask allows (its own node and a few neighbours), yet
the most likely action, sb3-contrib's masked mode (:func:`~sb3_pm.policies.heads.masked_mode`),
normalizes by a log-sum-exp over *every* node's logit. On large graphs the actor's work on the other
nodes is a large part of a deployed team's step, so
:class:`~sb3_pm.agents.deployment.team_forward.TeamForward` runs the policy's own actor on the
allowed nodes' inputs only and decides here, when that gives the same action; otherwise it
computes every logit.

**Same actions.** Every step of the masked mode is monotone in each logit up to rounding
(subtracting a common constant, masking, the softmax), so it returns the best allowed node unless
rounding ties or swaps two of them, which needs two allowed logits within a few units in the last
place of the largest normalized value. With a ``Tanh`` as the actor's last hidden layer
(``|h| <= 1``) every logit is at most ``L = |b| + sum |w|`` of the output layer in magnitude, and
every normalized value at most ``B = 2 L + log N``. A step is decided here only when its best
allowed logit leads the next by more than ``B * 2**-16`` (128 to 256 units in the last place of
``B``, far above the few units by which a logit computed on fewer rows may differ from the full
pass's); otherwise, or with a non-finite logit, the full pass decides. An untrained team's logits
all lie within about 1e-4, so its steps fall back; a trained team's are far apart on almost every
step. ``advice_prior`` lifts one logit past ``L``, so a team with it always computes every logit.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
import torch as th
from torch import nn

from sb3_pm.policies.policy import DCBFActorCriticPolicy

#: Graphs smaller than this compute every logit: on 50 nodes the indexing costs more than the
#: actor's work it saves.
MIN_NODES = 100
#: Fewest rows the actor runs on: with fewer, torch's CPU matrix products take a matrix-vector
#: path that sums in another order.
MIN_ROWS = 4
#: The decision margin, as a fraction of the bound ``B`` (module docstring).
MARGIN = 2.0**-16


def applies(policy: DCBFActorCriticPolicy) -> bool:
    """Whether ``policy``'s most likely actions may be decided from its allowed nodes' logits."""
    body = list(policy.actor_body)
    return (
        policy.n_nodes >= MIN_NODES
        and not policy.advice_prior
        and bool(body)
        and isinstance(body[-1], nn.Tanh)
        and not any(isinstance(layer, nn.Linear) and layer.out_features == 1 for layer in body)
    )


def margins(policies: Sequence[DCBFActorCriticPolicy], n_nodes: int) -> th.Tensor:
    """``(K,)`` float64: each policy's decision margin ``(2 L + log N) * MARGIN``."""
    with th.no_grad():
        bounds = [
            float(p.action_net.weight.double().abs().sum() + p.action_net.bias.double().abs().sum())
            for p in policies
        ]
    return (2.0 * th.tensor(bounds, dtype=th.float64) + math.log(n_nodes)) * MARGIN


def allowed_rows(masks: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
    """Per map, its allowed nodes in increasing order, padded to a common width of at least
    :data:`MIN_ROWS` by repeating the first.

    Shapes:
        - masks: ``(K, N)`` bool, no row all False
        - output: rows ``(K, S)`` long; candidate ``(K, S)`` bool, True on each allowed node's
          first (only) occurrence
    """
    lists = [np.flatnonzero(row).tolist() for row in masks.cpu().numpy()]
    width = max(MIN_ROWS, max(len(nodes) for nodes in lists))
    rows = th.tensor([nodes + [nodes[0]] * (width - len(nodes)) for nodes in lists], dtype=th.long)
    candidate = th.tensor([[i < len(nodes) for i in range(width)] for nodes in lists], dtype=th.bool)
    return rows, candidate


def decide(logits: th.Tensor, rows: th.Tensor, candidate: th.Tensor, margin: th.Tensor) -> np.ndarray | None:
    """Each map's best allowed node, or ``None`` if any map's best two allowed logits are within
    its margin, or a logit is not finite: the full pass must decide that step.

    Shapes:
        - logits, rows, candidate: ``(K, S)``; margin: ``(K,)``
        - output: ``(K,)`` int64
    """
    if not bool(th.isfinite(logits).all()):
        return None
    values = logits.double().masked_fill(~candidate, -math.inf)
    top = values.topk(2, dim=1).values  # (K, 2); the second is -inf where one node is allowed
    if not bool((top[:, 0] - top[:, 1] > margin).all()):
        return None
    return rows.gather(1, values.argmax(1, keepdim=True)).squeeze(1).numpy()  # type: ignore[no-any-return]


def allowed_actions(
    actor: Callable[[th.Tensor], th.Tensor],
    policies: Sequence[DCBFActorCriticPolicy],
    per_nodes: th.Tensor,
    masks: th.Tensor,
) -> np.ndarray | None:
    """The most likely actions ``(K,)`` from the allowed nodes' logits, or ``None`` where they do
    not decide them: ``actor`` (the policies' own actor bodies, ``(K, S, d) -> (K, S, w)``) on the
    allowed nodes' rows of the heads' inputs ``per_nodes`` ``(K, N, d)``, then each policy's own
    output layer; ``masks`` ``(K, N)`` bool."""
    rows, candidate = allowed_rows(masks)  # (K, S)
    hidden = actor(per_nodes.gather(1, rows.unsqueeze(-1).expand(-1, -1, per_nodes.shape[-1])))
    logits = []
    for k, policy in enumerate(policies):
        # The one-unit layer on a full-width copy, the other rows zero: a matrix-vector product
        # rounds by its length.
        wide = hidden.new_zeros((1, masks.shape[1], hidden.shape[-1]))
        wide[0, rows[k]] = hidden[k]
        logits.append(policy._actor_output(wide)[0, rows[k]])
    return decide(th.stack(logits), rows, candidate, margins(policies, masks.shape[1]))


__all__ = ["MIN_NODES", "allowed_actions", "allowed_rows", "applies", "decide", "margins"]
