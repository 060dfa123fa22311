"""A team's deterministic actions from the logits of the allowed nodes only, with the same actions.

An agent may move only to the nodes its DCBF mask allows (its own node and a few neighbours), yet
the stacked pass (:mod:`sb3_pm.agents.stacked_inference`) computes the actor's logit on every node
of the graph, and the last attention layer's output on every node too. On the published 200-node
graph the actor alone was a fifth of a deployed team's time. This pass computes, per map:

* the last GAT layer only on the allowed nodes and the agent's own node (the actor reads nothing
  else), each earlier layer only on the nodes the next one attends to (its rows' known neighbours
  and themselves), with every tensor that is summed over nodes kept at its full width ``N``, so a
  row's products run in the same kernels and orders as in the full pass;
* the actor on those rows only.

**Same logits on the rows it computes.** The rows are the full pass's rows bit for bit. Torch's
CPU kernels take another summation order for products with fewer than four rows, so a pass keeps
at least :data:`MIN_ROWS`; the one-output layer runs on a full-width copy with the other rows
zeroed. :class:`PrunedInference` checks this where it runs, on random maps and masks, and keeps
the full stacked pass for good if any bit differs.

**Same actions.** The full pass's action is sb3-contrib's masked mode, which normalizes by a
log-sum-exp over *every* node's logit; this pass does not have those. Every step of that
computation is monotone in each logit up to rounding (subtracting a common constant, masking, the
softmax), so it returns the best allowed node unless rounding ties or swaps two of them, which
needs two allowed logits within a few units in the last place of the largest normalized value.
The actor's last hidden layer is a ``Tanh`` (``|h| <= 1``), so every logit is at most
``L = |b| + sum |w|`` of the output layer in magnitude and every normalized value at most
``B = 2 L + log N`` (the log-sum-exp of ``N`` logits is below ``L + log N``; the second
normalization, over the allowed ones, adds at most ``log N`` more, well inside the margin's
slack). This pass decides
only when its best allowed logit leads the next by more than ``B * 2**-16`` (128 to 256 units in
the last place of ``B``) and otherwise runs the full pass for that step. A trained team's logits
are far apart on almost every step; an untrained team's all lie within about 1e-4, so it always
falls back. All of this holds for finite inputs: a step with a non-finite logit among the rows
falls back, but a non-finite value on a node the rows never reach would make the full pass's
mode differ (it then returns that node) where this pass does not see it.
:attr:`PrunedInference.counts` says how many steps each pass decided.

**Where it runs.** On graphs of at least :data:`MIN_NODES` nodes, where the stacked pass runs
(:func:`~sb3_pm.agents.stacked_inference.stack_problem`) and :func:`prune_problem` finds nothing
against it (it refuses ``advice_prior``, which lifts one logit past the bound the margin rests
on). ``tests/test_pruned_inference.py`` compares the actions with the serial path's on every
step of several episodes, checks the margin's fallback on built logits, and checks that a pass
that would round differently is refused.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import torch as th
from torch import nn

from sb3_pm.agents.stacked_inference import (
    _TRANSCENDENTAL,
    TAIL_FREE,
    StackedInference,
    _activation,
    _project,
    _Stack,
)
from sb3_pm.policies.attention import attention_probabilities
from sb3_pm.policies.extractor import GATFeaturesExtractor
from sb3_pm.policies.layers import GraphAttention
from sb3_pm.policies.policy import DCBFActorCriticPolicy, masked_mode, own_positions

#: Fewest rows a pruned product runs on: with fewer, torch's CPU matrix products take a
#: matrix-vector path that sums in another order than the full pass's.
MIN_ROWS = 4
#: Graphs smaller than this act through the full stacked pass: the pruned pass adds dozens of
#: small operations, and on 50 nodes they cost more than the arithmetic they save (300 steps of a
#: trained team: 0.67 s pruned against 0.48 s full on ``paper-50``, 0.64 against 0.71 s on
#: ``paper-100``, 0.78 against 1.28 s on ``paper-200``; docs/RESULTS.md §3i).
MIN_NODES = 100
#: The decision margin, as a fraction of the bound ``B`` on the normalized logits (module
#: docstring): a float32's unit in the last place is 2**-23 to 2**-24 of its magnitude, so this is
#: 128 to 256 of them.
MARGIN = 2.0**-16
#: Random draws of maps and masks on which a new stack's pruned rows are checked, and the mean
#: degrees of their known graphs: sparse maps give earlier layers tens of rows, as a real map does,
#: dense ones nearly all of them.
_CHECKS = 8
_CHECK_DEGREES = (2.0, 4.0, 8.0, 16.0)
#: The most allowed nodes a check draws per map (a high-degree node with its neighbours).
_CHECK_ALLOWED = 16


def prune_problem(policies: Sequence[DCBFActorCriticPolicy]) -> str | None:
    """Why ``policies`` (already able to act stacked) cannot act pruned, or ``None``."""
    first = policies[0]
    if first.advice_prior:
        return "advice_prior lifts the advised node's logit past the actor's bound"
    if first.n_nodes < MIN_NODES:
        return f"{first.n_nodes} nodes: below {MIN_NODES}, the full pass is faster"
    body = list(first.actor_body)
    if not body or not isinstance(body[-1], nn.Tanh):
        return "the actor's last hidden layer is not a Tanh, so its logits have no bound"
    if any(isinstance(layer, nn.Linear) and layer.out_features == 1 for layer in body):
        return "a one-unit hidden layer runs as a matrix-vector product, which rounds by its length"
    n = first.n_nodes
    if any((n * width) % TAIL_FREE for width in _transcendental_widths(first)):
        return (
            f"{n} nodes leave a transcendental activation's last elements outside its vector loop, "
            "where they round by their position"
        )
    return None


def _transcendental_widths(policy: DCBFActorCriticPolicy) -> list[int]:
    """The widths of the per-node tensors that a transcendental activation runs on."""
    extractor: GATFeaturesExtractor = policy.features_extractor  # type: ignore[assignment]
    widths: list[int] = []
    if isinstance(extractor.activation, _TRANSCENDENTAL):
        layers: list[GraphAttention] = list(extractor.gat)  # type: ignore[arg-type]
        widths += [int(layer.out_channels) for layer in layers]
    width = 0
    for layer in policy.actor_body:
        if isinstance(layer, nn.Linear):
            width = layer.out_features
        elif isinstance(layer, _TRANSCENDENTAL):
            widths.append(width)
    return widths


def row_multiple(policy: DCBFActorCriticPolicy) -> int:
    """The row counts a pruned pass pads to a multiple of, so that every transcendental activation
    runs on whole blocks of :data:`~sb3_pm.agents.stacked_inference.TAIL_FREE` elements, as the
    full pass does (see :func:`prune_problem`)."""
    multiple = 1
    for width in _transcendental_widths(policy):
        multiple = math.lcm(multiple, TAIL_FREE // math.gcd(width, TAIL_FREE))
    return multiple


def logit_bound(policy: DCBFActorCriticPolicy) -> float:
    """``L``: no logit of ``policy`` exceeds it in magnitude (its last hidden layer is a Tanh)."""
    head: nn.Linear = policy.action_net  # type: ignore[assignment]
    with th.no_grad():
        return float(head.weight.abs().sum() + head.bias.abs().sum())


class PrunedInference(StackedInference):
    """:class:`~sb3_pm.agents.stacked_inference.StackedInference` whose deterministic actions are
    decided from the allowed nodes' logits where that gives the same action (module docstring)."""

    def __init__(self) -> None:
        super().__init__()
        #: The stack (and thread count) :attr:`_prune_problem` was found for: a new stack is built
        #: for new policy objects, and holding it keeps those objects (and their ids) alive.
        self._prune_key: tuple[Any, int] | None = None
        self._prune_problem: str | None = None
        #: :func:`row_multiple` of the checked stack's architecture (fixed with the key).
        self._row_multiple = 1
        #: Decide from the pruned rows where possible (``False``: always the full stacked pass).
        self.prune = True
        #: How many steps were decided from the pruned rows, and how many ran the full pass.
        self.counts = {"pruned": 0, "full": 0}

    def prune_problem(self, policies: Sequence[Any]) -> str | None:
        """Why ``policies`` act through the full stacked pass rather than the pruned one (``None``:
        they act pruned), remembered per policy objects and thread count."""
        problem = self.problem(policies)
        if problem is not None:
            return problem
        key = (self._stack, th.get_num_threads())
        if self._prune_key is None or key[0] is not self._prune_key[0] or key[1] != self._prune_key[1]:
            self._prune_key, self._prune_problem = key, prune_problem(policies)
            self._row_multiple = row_multiple(policies[0])
            if self._prune_problem is None:
                assert self._stack is not None
                if not self._pruned_rows_match(self._stack):
                    self._prune_problem = "on this machine the pruned rows do not round as the full pass"
        return self._prune_problem

    def actions(
        self, policies: Sequence[Any], observations: Sequence[Mapping[str, Any]]
    ) -> np.ndarray | None:
        """As :meth:`StackedInference.actions`, deciding from the allowed nodes' logits where the
        margin allows it.

        Shapes:
            - observations: ``K`` mental-map observations (numpy), one per policy
            - output: ``(K,)`` int64
        """
        prepared = self.prepare(policies, observations)
        if prepared is None:
            return None
        pre, u_hat, masks = prepared
        stack = self._stack
        assert stack is not None
        if self.prune and self.prune_problem(policies) is None:
            with th.no_grad():
                rows, candidate = allowed_rows(masks, own_positions(pre), self._row_multiple)
                logits = self._pruned_logits(stack, pre, u_hat, rows)
                chosen = decide(logits, rows, candidate, self._margins(stack, masks.shape[1]))
            if chosen is not None:
                self.counts["pruned"] += 1
                return chosen
        self.counts["full"] += 1
        with th.no_grad():
            return masked_mode(self._logits_given(stack, pre, u_hat), masks).cpu().numpy()

    # ----------------------------------------------------------------- checks
    def _pruned_rows_match(self, stack: _Stack) -> bool:
        """Whether the pruned logits equal the full pass's on their rows, to the last bit, on random
        maps and masks (drawn from a generator of their own)."""
        rng = np.random.default_rng(1)
        n_nodes = stack.policies[0].n_nodes
        for draw in range(_CHECKS):
            degree = _CHECK_DEGREES[draw % len(_CHECK_DEGREES)]
            pre = self._random_maps(stack, rng, density=min(1.0, degree / max(n_nodes - 1, 1)))
            if pre is None:
                continue  # such maps never take the stacked pass
            k, n = pre["nodes"].shape[:2]
            masks = th.zeros((k, n), dtype=th.bool)
            for row in range(k):  # 1 to 16 allowed nodes per map
                count = int(rng.integers(1, min(n, _CHECK_ALLOWED) + 1))
                masks[row, rng.choice(n, size=count, replace=False)] = True
            with th.no_grad():
                u_hat = self._uncertainty(stack, pre)
                full = self._logits_given(stack, pre, u_hat)
                rows, _ = allowed_rows(masks, own_positions(pre), self._row_multiple)
                if not th.equal(self._pruned_logits(stack, pre, u_hat, rows), full.gather(1, rows)):
                    return False
        return True

    def _margins(self, stack: _Stack, n_nodes: int) -> th.Tensor:
        """``(K,)`` the decision margin of each policy (module docstring), from the stacked current
        weights: :func:`logit_bound` for every policy at once."""
        weight, bias = (
            stack.weights["action_net.weight"],
            stack.weights["action_net.bias"],
        )  # (K, 1, w), (K, 1)
        bound = weight.double().abs().sum((1, 2)) + bias.double().abs().sum(1)
        return (2.0 * bound + math.log(n_nodes)) * MARGIN

    # -------------------------------------------------------------- the pass
    def _pruned_logits(
        self, stack: _Stack, pre: dict[str, th.Tensor], u_hat: th.Tensor, rows: th.Tensor
    ) -> th.Tensor:
        """The logits ``(K, S)`` of the nodes ``rows`` ``(K, S)`` (the full pass's, bit for bit)."""
        first = stack.policies[0]
        embeddings = self._pruned_embed(stack, pre, rows)  # (K, S, h)
        own_column = (rows == own_positions(pre).unsqueeze(1)).int().argmax(1)  # where each map's node is
        own = embeddings[th.arange(rows.shape[0]), own_column]  # (K, h)
        if first.use_estimator:
            scaled = (u_hat / first.u_max).gather(1, rows)
            embeddings = th.cat((embeddings, scaled.unsqueeze(-1)), dim=-1)
        return self._pruned_actor(stack, embeddings, own, rows, pre["nodes"].shape[1])

    def _pruned_embed(self, stack: _Stack, pre: dict[str, th.Tensor], rows: th.Tensor) -> th.Tensor:
        """The last GAT layer's embeddings ``(K, S, h)`` of ``rows``; each earlier layer only on the
        rows the next attends to. Inputs of products stay ``N`` wide (other rows zero)."""
        extractor: GATFeaturesExtractor = stack.policies[0].features_extractor  # type: ignore[assignment]
        encoding, bias = self._graph_inputs(extractor, pre["adjacency"])
        attends = bias[:, 0] == 0  # (K, N, N): row i attends to column j (edges and self loops)
        needed = [rows]
        for _ in range(len(extractor.gat) - 1):
            needed.insert(0, neighbour_rows(attends, needed[0], self._row_multiple))
        x = extractor.node_features(pre)  # (K, N, F)
        batch, n, _ = x.shape
        for i, module in enumerate(extractor.gat):
            layer: GraphAttention = module  # type: ignore[assignment]
            h, a_dst, a_src = _project(stack, i, layer, x, encoding if i == 0 else None)
            heads = h.shape[1]
            wanted = needed[i]  # (K, R)
            r = wanted.shape[1]
            alpha = attention_probabilities(
                a_dst.gather(2, wanted.unsqueeze(1).expand(batch, heads, r)),
                a_src,
                bias.gather(2, wanted[:, None, :, None].expand(batch, 1, r, n)),
                float(layer.conv.negative_slope),
            )  # (K, H, R, N)
            layer_bias = stack.weights[f"features_extractor.gat.{i}.conv.bias"].unsqueeze(1)
            out = th.matmul(alpha, h).mean(1) + layer_bias  # (K, R, C)
            out = _activation(extractor.activation, out, r)
            if i == len(extractor.gat) - 1:
                return out
            x = th.zeros((batch, n, out.shape[-1]), dtype=out.dtype)
            x.scatter_(1, wanted.unsqueeze(-1).expand(-1, -1, out.shape[-1]), out)
        raise AssertionError("a GAT has at least one layer")

    @staticmethod
    def _pruned_actor(
        stack: _Stack, embeddings: th.Tensor, own: th.Tensor, rows: th.Tensor, n_nodes: int
    ) -> th.Tensor:
        """:meth:`StackedInference._actor` on the rows only: ``(K, S, d)`` -> ``(K, S)``."""
        hidden = StackedInference._actor_hidden(stack, embeddings, own)  # (K, S, w)
        return _output_layer(stack.policies, hidden, rows, n_nodes)


def _output_layer(
    policies: Sequence[DCBFActorCriticPolicy], hidden: th.Tensor, rows: th.Tensor, n_nodes: int
) -> th.Tensor:
    """Each policy's one-output layer on its map's rows: ``(K, S, w)`` -> ``(K, S)``. It runs on a
    full-width copy with the other rows zeroed, since a matrix-vector product rounds by its length."""
    wide = th.zeros((hidden.shape[0], n_nodes, hidden.shape[-1]), dtype=hidden.dtype)
    wide.scatter_(1, rows.unsqueeze(-1).expand(-1, -1, hidden.shape[-1]), hidden)
    logits = th.cat([p.action_net(wide[k : k + 1].clone()) for k, p in enumerate(policies)]).squeeze(-1)
    return logits.gather(1, rows)


def padded_rows(lists: list[list[int]], multiple: int) -> th.Tensor:
    """Each map's row list padded by repeating its first row to a common width: at least the
    longest list and :data:`MIN_ROWS`, a multiple of ``multiple`` (:func:`row_multiple`).
    ``(K, S)`` long."""
    width = max(MIN_ROWS, max(len(rows) for rows in lists))
    width = -(-width // multiple) * multiple
    return th.tensor([rows + [rows[0]] * (width - len(rows)) for rows in lists], dtype=th.long)


def allowed_rows(masks: th.Tensor, own: th.Tensor, multiple: int) -> tuple[th.Tensor, th.Tensor]:
    """Per map, its allowed nodes in increasing order and then its own node if not allowed, padded
    by repeating the first (:func:`padded_rows`).

    Shapes:
        - masks: ``(K, N)`` bool; own: ``(K,)`` long
        - output: rows ``(K, S)`` long; candidate ``(K, S)`` bool, True on each allowed node's
          first (only) occurrence
    """
    lists, flags = [], []
    for mask, node in zip(masks, own.tolist()):
        allowed = np.flatnonzero(mask.numpy()).tolist()
        extra = [] if mask[node] else [node]
        lists.append(allowed + extra)
        flags.append([True] * len(allowed) + [False] * len(extra))
    rows = padded_rows(lists, multiple)
    candidate = th.tensor([f + [False] * (rows.shape[1] - len(f)) for f in flags], dtype=th.bool)
    return rows, candidate


def neighbour_rows(attends: th.Tensor, rows: th.Tensor, multiple: int) -> th.Tensor:
    """The nodes ``rows`` ``(K, R)`` attend to (their known neighbours and themselves), per map,
    padded as :func:`allowed_rows` pads: ``(K, R')`` long."""
    reached = attends.gather(1, rows.unsqueeze(-1).expand(-1, -1, attends.shape[-1])).any(1)  # (K, N)
    return padded_rows([np.flatnonzero(row).tolist() for row in reached.numpy()], multiple)


def decide(logits: th.Tensor, rows: th.Tensor, candidate: th.Tensor, margins: th.Tensor) -> np.ndarray | None:
    """Each map's best allowed node, or ``None`` if any map's best two allowed logits are within its
    margin (or any logit is not finite): the full pass must decide that step.

    Shapes:
        - logits, rows, candidate: ``(K, S)``; margins: ``(K,)``
        - output: ``(K,)`` int64
    """
    if not bool(th.isfinite(logits).all()):
        return None
    values = logits.double().masked_fill(~candidate, -math.inf)
    top = values.topk(2, dim=1).values  # (K, 2); the second is -inf where one node is allowed
    if not bool((top[:, 0] - top[:, 1] > margins).all()):
        return None
    best = values.argmax(1, keepdim=True)
    return rows.gather(1, best).squeeze(1).numpy()


__all__ = [
    "MIN_ROWS",
    "PrunedInference",
    "allowed_rows",
    "decide",
    "logit_bound",
    "prune_problem",
    "row_multiple",
]
