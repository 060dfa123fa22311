"""What a team's one forward pass (:mod:`sb3_pm.agents.deployment.team_forward`) can run, and why not.

The pass maps the policy's own methods over the learners' stacked parameters, so the learners must
share one architecture, and a step's per-agent kernels must take no data-dependent branch (vmap
cannot trace one) and round alike on the learners' tensors at once.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import torch as th
from torch import nn

from sb3_pm.policies.attention import use_chunked, use_dense
from sb3_pm.policies.estimator import GATHER_MIN_ROWS
from sb3_pm.policies.extractor import GATFeaturesExtractor
from sb3_pm.policies.policy import DCBFActorCriticPolicy

#: Elements (a multiple of) that keep every element of an activation in its vectorized loop's
#: body: two vectors of the widest instruction set torch uses (2 x 16 floats), with a margin of 2.
TAIL_FREE = 64
#: Below this many elements torch runs an elementwise operation on one thread (its grain size).
_ONE_THREAD_ELEMENTS = 32_768
#: Activations that round the same wherever an element falls in the loop.
_EXACT = (nn.ReLU, nn.LeakyReLU, nn.Identity)
#: Constructor parameters that do not change what a policy computes when it acts.
_NOT_ARCHITECTURE = {"lr_schedule", "optimizer_class", "optimizer_kwargs", "estimator_lr"}
_NOT_ARCHITECTURE |= {"neglect_territory"}  # a filter setting, applied per learner


def team_problem(policies: Sequence[Any]) -> str | None:
    """Why ``policies`` cannot act as one team pass whatever their maps, or ``None`` if they can."""
    if not policies:
        return "no policies"
    if any(type(p) is not DCBFActorCriticPolicy for p in policies):
        return "not every policy is a DCBFActorCriticPolicy"
    if any(p.device.type != "cpu" for p in policies):
        return "the team pass is checked bit for bit on the CPU only"  # a GPU's kernels were not
    first = policies[0]
    extractor: GATFeaturesExtractor = first.features_extractor
    if not len(first.actor_body) or not isinstance(first.actor_body[0], nn.Linear):
        return "an actor without a hidden layer has no own-node product to run apart"
    if extractor.backend == "sparse":
        return "gat_backend: sparse runs the sparse kernel on every map"
    signature = _signature(first)
    if any(_signature(p) != signature for p in policies[1:]):
        return "the policies differ in more than their parameters"
    return None


def _signature(policy: DCBFActorCriticPolicy) -> tuple[Any, ...]:
    """Everything but the parameters (and the DCBF territory) that decides what ``policy``
    computes when it acts."""
    data = policy._get_constructor_parameters()
    kept = sorted((key, repr(value)) for key, value in data.items() if key not in _NOT_ARCHITECTURE)
    config = policy.dcbf_config
    return (
        repr(policy),
        kept,
        replace(config, territory=()),
        policy.device,
        tuple((name, tuple(t.shape), t.dtype) for name, t in policy.named_parameters()),
        # every map is scaled by the first policy's buffers (the observation space's highs)
        tuple((name, t.detach().cpu().numpy().tobytes()) for name, t in policy.named_buffers()),
    )


def shape_problem(policy: DCBFActorCriticPolicy, adjacency: th.Tensor, maps: int) -> str | None:
    """Why ``maps`` maps per policy (adjacencies ``(K * maps, N, N)``) cannot be mapped over the
    learners: one pass per policy would take a kernel with data-dependent branches, or the
    batched pass would round otherwise."""
    extractor: GATFeaturesExtractor = policy.features_extractor  # type: ignore[assignment]
    n = adjacency.shape[-1]
    if any(use_chunked(maps, int(layer.heads), n, adjacency.device.type == "cpu") for layer in extractor.gat):
        return f"{maps} maps of {n} nodes take the chunked attention kernel"
    if policy.estimator is not None and maps * n >= GATHER_MIN_ROWS:
        return f"{maps} maps of {n} nodes take the estimator's row gathering"
    for start in range(0, adjacency.shape[0], maps):
        if not use_dense(adjacency[start : start + maps], extractor.backend):
            return "a policy's maps would take the sparse attention kernel"
    k = adjacency.shape[0] // maps
    for size in _activation_sizes(policy, maps):
        # A vectorized elementwise loop computes its last elements with scalar code, which rounds
        # transcendental functions otherwise; on the K learners' tensor at once those elements
        # fall elsewhere, unless each learner's part is whole blocks and one thread runs it all.
        if size % TAIL_FREE or (th.get_num_threads() > 1 and k * size >= _ONE_THREAD_ELEMENTS):
            return f"{maps} maps of {n} nodes leave an activation's elements outside its vector loop"
    return None


def _activation_sizes(policy: DCBFActorCriticPolicy, maps: int) -> list[int]:
    """The elements of each tensor the mapped part of a policy's pass on ``maps`` maps applies a
    transcendental activation to (the GAT's and the actor's)."""
    extractor: GATFeaturesExtractor = policy.features_extractor  # type: ignore[assignment]
    n = policy.n_nodes
    sizes: list[int] = []
    if not isinstance(extractor.activation, _EXACT):
        sizes += [maps * n * int(layer.out_channels) for layer in extractor.gat]
    width = 0
    for layer in policy.actor_body:
        if isinstance(layer, nn.Linear):
            width = layer.out_features
        elif not isinstance(layer, _EXACT):
            sizes.append(maps * n * width)
    return sizes


__all__ = ["TAIL_FREE", "shape_problem", "team_problem"]
