"""One forward pass for a whole team: the learners' policies run stacked, each with its own weights.

A deployed team acts with one small forward pass per agent per step, each made of about 150
small tensor operations, so a team's evaluation spends its time on per-operation overhead rather
than arithmetic. When the learners' policies share one architecture (always, for a team built
from one config), each parameter can be stacked along a new leading axis and every agent's pass
becomes one batched operation on ``K`` maps: a batched matrix product with each map's own weights,
an elementwise operation on the stacked tensors.

Nothing is shared but the arithmetic: agent ``k``'s action depends only on its own observation and
its own learner's parameters, as in the serial path. The parameter-free parts (SB3's
preprocessing, the DCBF filter, the positional encodings, the attention masks) run on the batch
of ``K`` maps as they are.

**Bit for bit.** The stacked pass computes the serial pass's logits exactly, and it checks that
it does: when it first serves a set of policies (and again when torch's thread count changes), it
computes logits for random maps both ways and, if any bit differs, says so and leaves that team to
the serial path for good. Which batched kernels round as the single-map ones is a property of the
CPU, the BLAS library and the sizes, so it is verified where it runs rather than assumed.
``tests/test_stacked_inference.py`` also compares the two on every step of several episodes. To
round as the serial path does, the pass:

* runs map by map, on the learners' own tensors, every product with one output unit (the actor's
  logit, the estimator's prediction) or one input row (the actor's product with the own node's
  embedding): alone, they run as matrix-vector kernels whose summation order no batched kernel
  reproduces;
* batches a transcendental activation (ELU, Tanh) only when each map fills whole blocks of
  :data:`TAIL_FREE` elements and one thread computes it: its vectorized loop computes leftover
  elements with scalar code, and torch splits a large tensor between threads at other boundaries,
  so where an element falls in the loop would otherwise depend on the batch. With the default
  sizes (32 and 64 units, an even number of nodes) it stays batched.

Sampled actions (:meth:`StackedInference.sampled_actions`) take the stacked logits and then draw
policy by policy, in the team's order, each from its own row at its own policy's temperature, as
the serial path draws them: the same logits give the same distribution, and torch's generator is
consumed in the same order, so the draws are the serial path's too.

This pass covers the configurations the package trains by default: the dense GAT kernel, the
estimator (or none), any positional encoding, one or more heads, an actor with a hidden layer, and
the fixed ``advice_prior`` on the advised node's logit.
A step runs serially instead (:meth:`StackedInference.actions` and
:meth:`StackedInference.sampled_actions` return ``None``, and
:func:`stack_problem` says why) for other policies, policies that differ in anything but their
parameters, policies off the CPU (not verified there), graphs large enough for the chunked
attention kernel or the estimator's row gathering, a map the dense kernel would not run, an observation of another shape (the serial
path then raises SB3's error), or a failed check of the rounding.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any, NamedTuple

import numpy as np
import torch as th
from torch import nn

from sb3_pm.envs.mental_map import TARGET
from sb3_pm.policies.attention import FUSED_MIN_SCORES, attention_bias, attention_probabilities, use_dense
from sb3_pm.policies.estimator import GATHER_MIN_ROWS, StateEstimator
from sb3_pm.policies.extractor import GATFeaturesExtractor
from sb3_pm.policies.layers import GraphAttention
from sb3_pm.policies.policy import MAP_KEYS, DCBFActorCriticPolicy, masked_mode

#: Elements per map (a multiple of) that keep every element of a transcendental activation in its
#: vectorized loop's body: two vectors of the widest instruction set torch uses (2 x 16 floats),
#: with a margin of 2.
TAIL_FREE = 64
#: Random draws of maps on which a new stack's rounding is checked (some roundings differ only
#: for some values, as a transcendental function's vector and scalar code do).
_CHECKS = 8
#: Below this many elements torch runs an elementwise operation on one thread (its grain size is
#: 32,768), so a batched activation is split between threads at no boundary of its own.
_ONE_THREAD_ELEMENTS = 32_768
#: Constructor parameters that do not change what a policy computes when it acts.
#: (a learner's own territory is a filter setting that the stacked pass applies per learner)
_NOT_ARCHITECTURE = (
    "lr_schedule",
    "optimizer_class",
    "optimizer_kwargs",
    "estimator_lr",
    "neglect_territory",
)
_TRANSCENDENTAL = (nn.ELU, nn.Tanh, nn.Sigmoid, nn.GELU, nn.SiLU, nn.Softplus, nn.Mish, nn.CELU, nn.SELU)
_EXACT = (nn.ReLU, nn.LeakyReLU, nn.Identity)


def stack_problem(policies: Sequence[Any]) -> str | None:
    """Why ``policies`` cannot act as one stacked pass, or ``None`` if they can."""
    if not policies:
        return "no policies"
    first = policies[0]
    if any(type(p) is not DCBFActorCriticPolicy for p in policies):
        return "not every policy is a DCBFActorCriticPolicy"
    if any(p.device.type != "cpu" for p in policies):
        return "the stacked pass is verified on the CPU only"
    extractor = first.features_extractor
    if extractor.backend == "sparse":
        return "gat_backend: sparse runs the sparse kernel on every map"
    if len(first.actor_body) == 0 or not isinstance(first.actor_body[0], nn.Linear):
        return "an actor without a hidden layer is not stacked"
    layers = [*first.actor_body, *(first.estimator.net if first.estimator is not None else [])]
    if any(not isinstance(layer, (nn.Linear, *_TRANSCENDENTAL, *_EXACT)) for layer in layers) or any(
        isinstance(layer, nn.Linear) and layer.bias is None for layer in layers
    ):
        return "a head with a layer other than Linear (with bias) and a plain activation is not stacked"
    names = dict(first.named_parameters())
    needed = ["actor_body.0.weight", "actor_body.0.bias"] + [
        f"features_extractor.gat.{i}.conv.{name}"
        for i in range(len(extractor.gat))
        for name in ("lin.weight", "att_src", "att_dst", "bias")
    ]
    if any(name not in names for name in needed):
        return "the GAT or actor parameters are not laid out as this pass expects"
    n = first.n_nodes
    heads = max(layer.heads for layer in extractor.gat)
    if heads * n * n >= FUSED_MIN_SCORES or n >= GATHER_MIN_ROWS:
        return f"{n} nodes take the chunked attention or the estimator's row gathering"
    signature = _signature(first)
    for policy in policies[1:]:
        if _signature(policy) != signature:
            return "the policies differ in more than their parameters"
    return None


def _signature(policy: DCBFActorCriticPolicy) -> tuple[Any, ...]:
    """Everything but the parameters that decides what ``policy`` computes when it acts."""
    data = policy._get_constructor_parameters()
    kept = {key: value for key, value in data.items() if key not in _NOT_ARCHITECTURE}
    return (
        repr(policy),
        sorted(kept.items(), key=lambda item: item[0]),
        _filter_but_territory(policy),
        policy.use_dcbf,
        policy.u_max,
        policy.device,
        tuple((name, tuple(t.shape), t.dtype) for name, t in policy.named_parameters()),
        # every map is scaled by the first policy's buffers (the observation space's highs)
        tuple((name, t.detach().cpu().numpy().tobytes()) for name, t in policy.named_buffers()),
    )


class RolloutHeads(NamedTuple):
    """One policy's rollout step from the stacked pass (see :meth:`StackedInference.rollout_heads`)."""

    logits: th.Tensor  #: ``(B, N)``
    values: th.Tensor  #: ``(B, 1)``
    masks: th.Tensor  #: ``(B, N)`` bool, the DCBF masks
    forced: th.Tensor | None  #: ``(B,)`` bool, where rule 8 forced the mask (``None``: rule 8 off)


class _Stack:
    """The stacked parameters of ``K`` policies, ``(K, *shape)`` each, by parameter name."""

    def __init__(self, policies: Sequence[DCBFActorCriticPolicy]) -> None:
        self.policies = list(policies)
        self.names = [name for name, _ in policies[0].named_parameters()]
        # The parameter objects, found once (walking the module tree each step cost more than the
        # stacking); their values are read anew on every refresh.
        self.sources = [[dict(p.named_parameters())[name] for name in self.names] for p in policies]
        self.weights: dict[str, th.Tensor] = {}

    def refresh(self) -> None:
        """Stack the policies' current values. Done on every call (a small fraction of a step): a
        cache keyed on torch's version counters missed writes through ``.data``, which PyG's
        initializers and ``Module.to`` make. A parameter object replaced outright
        (``load_state_dict(assign=True)``) needs a new stack: :class:`StackedInference` builds one
        for new policy objects, not for new parameters of the same ones."""
        with th.no_grad():
            self.weights = {name: th.stack(group) for name, group in zip(self.names, zip(*self.sources))}


class StackedInference:
    """Actions of several DCBF policies (most likely, or drawn) from one stacked forward pass.

    Remembers, for the last policy list it served, whether they can act stacked (and whether the
    stacked pass rounds as the serial one here, per torch thread count); the parameters themselves
    are stacked anew on every call.
    """

    def __init__(self) -> None:
        self._ids: tuple[int, ...] | None = None
        self._problem: str | None = None
        #: (adjacencies, encodings, attention masks) of the last call: an agent's known map changes
        #: only when it discovers an edge, so most steps reuse them (as the serial path's extractor does)
        self._graph_cache: tuple[th.Tensor, th.Tensor | None, th.Tensor] | None = None
        self._stack: _Stack | None = None

    def problem(self, policies: Sequence[Any], maps: int = 1, values: bool = False) -> str | None:
        """Why ``policies`` cannot act stacked now, ``maps`` maps each (``values``: the critic's
        values are wanted too): :func:`stack_problem`, or a failed check of the rounding
        (remembered for the same policy objects, thread count and batch; the filter settings,
        which deployment may change, are compared on every call)."""
        ids = (*(id(p) for p in policies), th.get_num_threads(), maps, values)
        if ids != self._ids:
            self._ids, self._problem = ids, stack_problem(policies)
            if self._problem is None and maps * policies[0].n_nodes >= GATHER_MIN_ROWS:
                self._problem = (
                    f"{maps} maps of {policies[0].n_nodes} nodes take the estimator's row gathering"
                )
            self._graph_cache = None  # other policies may encode the same maps differently
            self._stack = None if self._problem is not None else _Stack(policies)
            if self._stack is not None and not self._rounds_as_serial(self._stack, maps, values):
                self._problem = "on this machine the stacked pass does not round as the serial one"
                self._stack = None
        if self._problem is None:  # DCBF policies only, so each has a filter to compare
            settings = _filter_but_territory(policies[0])
            if any(_filter_but_territory(p) != settings for p in policies):
                return "the policies' DCBF filter settings differ"
        return self._problem

    def _rounds_as_serial(self, stack: _Stack, maps: int = 1, values: bool = False) -> bool:
        """Whether the stacked logits (and with ``values`` the masks and values) equal each
        policy's own on random batches of ``maps`` maps of its observation space, to the last bit
        (drawn from a generator of their own: nothing else's state moves)."""
        rng = np.random.default_rng(0)
        return all(self._rounds_as_serial_on(stack, rng, maps, values) for _ in range(_CHECKS))

    def _rounds_as_serial_on(self, stack: _Stack, rng: np.random.Generator, maps: int, values: bool) -> bool:
        """One draw of :meth:`_rounds_as_serial`."""
        pre = self._random_maps(stack, rng, maps)
        if pre is None:
            return True  # such maps never take this pass
        n = pre["nodes"].shape[1]
        with th.no_grad():
            u_hat = self._uncertainty(stack, pre)
            if values:
                masks, _ = _filtered_masks(stack.policies, pre, u_hat, None)
                stacked, stacked_values = self._heads_given(stack, pre, u_hat)
            else:
                masks = th.ones((len(stack.policies) * maps, n), dtype=th.bool)
                stacked = self._logits_given(stack, pre, u_hat)
            for i, policy in enumerate(stack.policies):
                rows = slice(i * maps, (i + 1) * maps)
                alone = {key: value[rows].clone() for key, value in pre.items()}
                alone_u = policy.uncertainty(alone)
                if values:
                    alone_masks, _ = policy.filtered_masks(alone, alone_u, None)
                    serial, serial_values = policy._heads(alone, alone_u, alone_masks)
                    if not (
                        th.equal(alone_masks, masks[rows]) and th.equal(serial_values, stacked_values[rows])
                    ):
                        return False
                else:
                    serial = policy._logits(alone, alone_u, masks[rows])
                if not th.equal(serial, stacked[rows]):
                    return False
        return True

    def _random_maps(
        self, stack: _Stack, rng: np.random.Generator, maps: int = 1, density: float = 0.3
    ) -> dict[str, th.Tensor] | None:
        """Preprocessed random maps of the policies' observation space, ``maps`` per policy (policy
        ``k``'s are rows ``k * maps`` to ``(k + 1) * maps - 1``), each edge known with probability
        ``density``, with the stack refreshed (``None`` if they would not take the dense kernel,
        hence not this pass)."""
        first = stack.policies[0]
        space = first.observation_space
        k, n = len(stack.policies) * maps, first.n_nodes
        nodes_space = space["nodes"]  # type: ignore[index]
        nodes = rng.uniform(0.0, 1.0, (k, *nodes_space.shape)) * nodes_space.high
        nodes = np.round(nodes).astype(nodes_space.dtype)  # the env's counters are integers
        upper = np.triu(rng.random((k, n, n)) < density, 1)
        adjacency = (upper | upper.transpose(0, 2, 1)).astype(space["adjacency"].dtype)  # type: ignore[index]
        position = rng.integers(0, n, k)
        mask = adjacency.astype(bool)[np.arange(k), position]  # a reachable set: the node and its neighbours
        mask[np.arange(k), position] = True
        arrays = {
            "nodes": th.as_tensor(nodes),
            "adjacency": th.as_tensor(adjacency),
            "position": th.as_tensor(position),
            "dwell": th.as_tensor(rng.integers(0, 5, (k, 1)).astype(np.float32)),
            "action_mask": th.as_tensor(mask.astype(np.int8)),
        }
        if not _all_dense(first, arrays["adjacency"], maps):
            return None
        stack.refresh()
        with th.no_grad():
            return first._preprocess(arrays)  # type: ignore[no-any-return]

    def actions(
        self, policies: Sequence[Any], observations: Sequence[Mapping[str, Any]]
    ) -> np.ndarray | None:
        """The most likely action of ``policies[k]`` on ``observations[k]`` for every ``k``, as the
        serial ``policy.predict(obs, deterministic=True, action_masks=obs["action_mask"])`` gives
        it; ``None`` where this step must run serially (see the module docstring).

        Shapes:
            - observations: ``K`` mental-map observations (numpy), one per policy
            - output: ``(K,)`` int64
        """
        result = self.logits(policies, observations)
        if result is None:
            return None
        logits, masks = result
        return masked_mode(logits, masks).cpu().numpy()

    def sampled_actions(
        self, policies: Sequence[Any], observations: Sequence[Mapping[str, Any]]
    ) -> np.ndarray | None:
        """An action of ``policies[k]`` drawn on ``observations[k]`` for every ``k``, as the serial
        ``policy.predict(obs, deterministic=False, action_masks=obs["action_mask"])`` calls draw
        them one after another: each policy's own row of the stacked logits, at its own
        ``sampling_temperature``, through its own distribution, in the order of ``policies``.
        ``None`` where this step must run serially. Shapes as :meth:`actions`.
        """
        result = self.logits(policies, observations)
        if result is None:
            return None
        logits, masks = result
        actions = np.empty(len(policies), dtype=np.int64)
        with th.no_grad():
            for k, policy in enumerate(policies):  # the serial pass's (1, N) row, its own draw
                actions[k] = int(policy.draw(logits[k : k + 1], masks[k : k + 1]).reshape(-1)[0])
        return actions

    def logits(
        self, policies: Sequence[Any], observations: Sequence[Mapping[str, Any]]
    ) -> tuple[th.Tensor, th.Tensor] | None:
        """Every policy's logits on its own observation and its DCBF mask, or ``None`` where this
        step must run serially. Counts rule 8's decisions in each policy's ``filter_counts``.

        Shapes:
            - observations: ``K`` mental-map observations (numpy), one per policy
            - output: logits ``(K, N)`` float, masks ``(K, N)`` bool
        """
        prepared = self.prepare(policies, observations)
        if prepared is None:
            return None
        pre, u_hat, masks = prepared
        assert self._stack is not None
        with th.no_grad():
            return self._logits_given(self._stack, pre, u_hat), masks

    def prepare(
        self, policies: Sequence[Any], observations: Sequence[Mapping[str, Any]]
    ) -> tuple[dict[str, th.Tensor], th.Tensor, th.Tensor] | None:
        """The stacked pass up to the actor on one map per policy, acted on as ``predict`` does
        (the observation's ``action_mask`` intersected with the filter's): the preprocessed maps,
        every policy's ``û`` on its own map and its DCBF mask (counting rule 8's decisions), with
        the parameters stacked anew; ``None`` where this step must run serially.

        Shapes:
            - observations: ``K`` mental-map observations (numpy), one per policy
            - output: the maps (``(K, ...)`` each), ``û`` ``(K, N)``, masks ``(K, N)`` bool
        """
        prepared = self._prepare(policies, observations, None)
        if prepared is None:
            return None
        pre, u_hat, masks, forced = prepared
        if forced is not None:
            for k, policy in enumerate(policies):
                policy.count_forced(forced[k : k + 1])
        return pre, u_hat, masks

    def _prepare(
        self, policies: Sequence[Any], observations: Sequence[Mapping[str, Any]], maps: int | None
    ) -> tuple[dict[str, th.Tensor], th.Tensor, th.Tensor, th.Tensor | None] | None:
        """:meth:`prepare` without counting, also for ``maps`` maps per policy (a rollout's batch,
        masked by the filter alone, as ``rollout_heads`` masks): adds rule 8's decisions
        ``(K * maps,)`` bool (``None`` when rule 8 is off)."""
        batch = 1 if maps is None else maps
        if len(policies) != len(observations) or self.problem(policies, batch, maps is not None) is not None:
            return None
        stack = self._stack
        assert stack is not None
        first: DCBFActorCriticPolicy = policies[0]
        space = first.observation_space
        arrays = {}
        for key in MAP_KEYS:
            shape = space[key].shape  # type: ignore[index]
            values = [np.asarray(obs[key]) for obs in observations]
            allowed = (shape, (1, *shape)) if maps is None else ((maps, *shape),)
            if any(v.shape not in allowed for v in values):
                return None  # the serial path raises SB3's error for it
            arrays[key] = th.as_tensor(np.concatenate([v.reshape(batch, *shape) for v in values]))  # CPU only
        if not _all_dense(first, arrays["adjacency"], batch):
            return None  # a map the serial path would run through the sparse kernel
        for policy in policies:
            policy.set_training_mode(False)  # as SB3's predict and collect_rollouts do
        stack.refresh()
        with th.no_grad():
            pre = first._preprocess(arrays)
            u_hat = self._uncertainty(stack, pre)
            given = arrays["action_mask"] if maps is None else None
            masks, forced = _filtered_masks(policies, pre, u_hat, given)
            return pre, u_hat, masks, forced

    def rollout_heads(
        self, policies: Sequence[Any], observations: Sequence[Mapping[str, Any]]
    ) -> list[RolloutHeads] | None:
        """Every policy's :meth:`~sb3_pm.policies.DCBFActorCriticPolicy.rollout_heads` on its own
        batch of maps (a learner's ``VecEnv`` observation), bit for bit, with the rule-8 decisions
        that call would count (counted by nobody here: the caller counts each policy's when it
        uses them); ``None`` where this step must run serially.

        Shapes:
            - observations: ``K`` observations (numpy dicts), each ``(B, ...)`` per key
            - output: per policy, logits ``(B, N)``, values ``(B, 1)``, masks ``(B, N)`` bool and
              rule 8's decisions ``(B,)`` bool (``None`` when rule 8 is off)
        """
        if not observations or "nodes" not in observations[0]:
            return None
        maps = int(np.shape(observations[0]["nodes"])[0])
        prepared = self._prepare(policies, observations, maps)
        if prepared is None:
            return None
        pre, u_hat, masks, forced = prepared
        assert self._stack is not None
        with th.no_grad():
            logits, values = self._heads_given(self._stack, pre, u_hat)
        groups = _groups(self._stack, logits)
        return [
            RolloutHeads(logits[rows], values[rows], masks[rows], None if forced is None else forced[rows])
            for rows in groups
        ]

    def predict(
        self,
        observations: Mapping[str, Mapping[str, Any]],
        policy_for: Callable[[str], Any],
        deterministic: bool = True,
    ) -> dict[str, int] | None:
        """A team's actions ``{agent: node}``, agent ``a`` acting with ``policy_for(a)``: the most
        likely ones, or with ``deterministic=False`` drawn agent by agent in the order of
        ``observations``; ``None`` where this step must run serially."""
        agents = list(observations)
        if not agents:
            return None
        policies, maps = [policy_for(a) for a in agents], [observations[a] for a in agents]
        actions = self.actions(policies, maps) if deterministic else self.sampled_actions(policies, maps)
        return None if actions is None else {agent: int(action) for agent, action in zip(agents, actions)}

    # -------------------------------------------------------------- the pass
    def _uncertainty(self, stack: _Stack, pre: dict[str, th.Tensor]) -> th.Tensor:
        """``û`` ``(K * B, N)``: each policy's ``uncertainty`` on its own ``B`` maps."""
        first = stack.policies[0]
        return self._estimate(stack, pre) if first.estimator is not None else first.uncertainty(pre)

    def _logits_given(self, stack: _Stack, pre: dict[str, th.Tensor], u_hat: th.Tensor) -> th.Tensor:
        """Each policy's logits ``(K * B, N)`` on its own ``B`` maps, given ``û`` ``(K * B, N)``."""
        first = stack.policies[0]
        logits = self._actor(stack, *first._with_estimate(self._embed(stack, pre), pre, u_hat))
        # advice_prior is a constructor parameter, so every stacked policy has the same one; the
        # serial pass adds it elementwise, which rounds the same on any batch.
        return first._with_advice(logits, pre)

    def _heads_given(
        self, stack: _Stack, pre: dict[str, th.Tensor], u_hat: th.Tensor
    ) -> tuple[th.Tensor, th.Tensor]:
        """Each policy's logits ``(K * B, N)`` and values ``(K * B, 1)`` on its own ``B`` maps. The
        critic (its layers on ``B`` rows, a small part of the pass) runs policy by policy, on its
        own modules."""
        first = stack.policies[0]
        embeddings, own = first._with_estimate(self._embed(stack, pre), pre, u_hat)
        groups = _groups(stack, embeddings)
        values = th.cat(
            [p._value(embeddings[rows].clone(), own[rows].clone()) for p, rows in zip(stack.policies, groups)]
        )
        return first._with_advice(self._actor(stack, embeddings, own), pre), values

    @staticmethod
    def _mlp(stack: _Stack, prefix: str, layers: nn.Sequential, x: th.Tensor, start: int = 0) -> th.Tensor:
        """``layers[start:]`` on ``x`` ``(K * B, N, d)``, each policy's ``B`` maps with its own weights."""
        n = x.shape[1]
        k = len(stack.policies)
        for i, layer in enumerate(layers):
            if i < start:
                continue
            if isinstance(layer, nn.Linear):
                if layer.out_features == 1:
                    x = _per_map(stack, f"{prefix}.{i}", x)
                else:
                    weight, bias = stack.weights[f"{prefix}.{i}.weight"], stack.weights[f"{prefix}.{i}.bias"]
                    rows = x.shape[0] * n // k
                    x = th.baddbmm(bias.unsqueeze(1), x.reshape(k, rows, -1), weight.transpose(1, 2))
                    x = x.view(-1, n, x.shape[-1])
            else:
                x = _activation(layer, x, n, k)
        return x

    def _estimate(self, stack: _Stack, pre: dict[str, th.Tensor]) -> th.Tensor:
        """``û`` ``(K * B, N)``: :meth:`StateEstimator.forward
        <sb3_pm.policies.estimator.StateEstimator.forward>` per policy (its ``B`` maps' rows are
        below the estimator's row-gathering size)."""
        first = stack.policies[0]
        estimator: StateEstimator | None = first.estimator  # type: ignore[assignment]
        assert estimator is not None
        nodes = pre["nodes"]  # the normalization is the observation space's, the same for every policy
        out = self._mlp(stack, "estimator.net", estimator.net, nodes * estimator.inv_high).squeeze(-1)
        out = out * nodes[..., TARGET]
        return out.clamp(0.0, 1.0) * estimator.u_max

    def _graph_inputs(
        self, extractor: GATFeaturesExtractor, adjacency: th.Tensor
    ) -> tuple[th.Tensor | None, th.Tensor]:
        """Positional encodings ``(K * B, N, E)`` (or ``None``) and attention masks
        ``(K * B, 1, N, N)`` of the maps' known adjacencies ``(K * B, N, N)``, reused while the
        adjacencies are unchanged."""
        cached = self._graph_cache
        if cached is not None and cached[0].shape == adjacency.shape and th.equal(cached[0], adjacency):
            return cached[1], cached[2]
        encoding, bias = extractor.encoding(adjacency), attention_bias(adjacency)
        self._graph_cache = (adjacency.clone(), encoding, bias)
        return encoding, bias

    def _embed(self, stack: _Stack, pre: dict[str, th.Tensor]) -> th.Tensor:
        """The GAT embeddings ``(K * B, N, h)``: ``GATFeaturesExtractor.node_embeddings`` on the
        dense kernel, each policy's ``B`` maps with its own weights."""
        extractor: GATFeaturesExtractor = stack.policies[0].features_extractor  # type: ignore[assignment]
        adjacency = pre["adjacency"]
        encoding, bias = self._graph_inputs(extractor, adjacency)
        x = extractor.node_features(pre)  # (K * B, N, F): scaled by the observation space's highs
        n = x.shape[1]
        k = len(stack.policies)
        for i, module in enumerate(extractor.gat):
            layer: GraphAttention = module  # type: ignore[assignment]
            h, a_dst, a_src = _project(stack, i, layer, x, encoding if i == 0 else None)
            alpha = attention_probabilities(a_dst, a_src, bias, float(layer.conv.negative_slope))
            layer_bias = _per_policy(stack.weights[f"features_extractor.gat.{i}.conv.bias"], x.shape[0] // k)
            out = th.matmul(alpha, h).mean(1) + layer_bias.unsqueeze(1)
            x = _activation(extractor.activation, out, n, k)
        return x

    @staticmethod
    def _actor(stack: _Stack, embeddings: th.Tensor, own: th.Tensor) -> th.Tensor:
        """``DCBFActorCriticPolicy._actor_logits`` per policy: ``(K * B, N)``."""
        return _per_map(stack, "action_net", StackedInference._actor_hidden(stack, embeddings, own)).squeeze(
            -1
        )

    @staticmethod
    def _actor_hidden(stack: _Stack, embeddings: th.Tensor, own: th.Tensor) -> th.Tensor:
        """The actor body per policy, on every row given: ``(K * B, R, d)``, own ``(K * B, h)`` ->
        ``(K * B, R, w)`` (policy ``k``'s ``B`` maps first)."""
        policies = stack.policies
        width = embeddings.shape[-1]
        weight, bias = stack.weights["actor_body.0.weight"], stack.weights["actor_body.0.bias"]
        per_node = th.baddbmm(
            bias.unsqueeze(1),
            embeddings.reshape(len(policies), -1, width),
            weight[:, :, :width].transpose(1, 2),
        ).view(*embeddings.shape[:-1], -1)
        # The product with the own node's embedding has one row per map: policy by policy, as the
        # serial path computes it on its B maps (see the module docstring).
        per_map = th.cat(
            [
                nn.functional.linear(own[rows].clone(), _first_weight(p)[:, width:])
                for p, rows in zip(policies, _groups(stack, own))
            ]
        ).unsqueeze(1)  # (K * B, 1, w)
        return StackedInference._mlp(stack, "actor_body", policies[0].actor_body, per_node + per_map, start=1)


def _project(
    stack: _Stack, index: int, layer: GraphAttention, x: th.Tensor, encoding: th.Tensor | None
) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
    """GAT layer ``index``'s projection of every node, each policy's ``B`` maps with its own
    weights: ``h`` ``(K * B, H, N, C)`` and the attention terms ``a_dst``, ``a_src``
    ``(K * B, H, N)`` (``GraphAttention._project``, with the first layer's positional ``encoding``
    ``(K * B, N, E)``)."""
    prefix = f"features_extractor.gat.{index}.conv"
    weight = stack.weights[f"{prefix}.lin.weight"]  # (K, heads * C, F [+ E])
    batch, n, features = x.shape
    k = weight.shape[0]
    heads, channels = int(layer.heads), int(layer.out_channels)
    by_policy = x.reshape(k, -1, features)  # (K, B * N, F)
    if encoding is not None:
        h = th.bmm(by_policy, weight[:, :, :features].transpose(1, 2)) + th.matmul(
            encoding.reshape(k, -1, encoding.shape[-1]), weight[:, :, features:].transpose(1, 2)
        )
    else:
        h = th.bmm(by_policy, weight.transpose(1, 2))
    h = h.view(batch, n, heads, channels).transpose(1, 2).contiguous()  # (K * B, H, N, C)
    att_src = _per_policy(stack.weights[f"{prefix}.att_src"], batch // k).view(batch, heads, 1, channels)
    att_dst = _per_policy(stack.weights[f"{prefix}.att_dst"], batch // k).view(batch, heads, 1, channels)
    return h, (h * att_dst).sum(-1), (h * att_src).sum(-1)


def _all_dense(policy: DCBFActorCriticPolicy, adjacency: th.Tensor, maps: int = 1) -> bool:
    """Whether the serial path would run every map of ``adjacency`` ``(K * maps, N, N)`` through
    the dense kernel (it decides per call, and a serial call holds one policy's ``maps`` maps)."""
    extractor: GATFeaturesExtractor = policy.features_extractor  # type: ignore[assignment]
    return all(
        use_dense(adjacency[start : start + maps], extractor.backend)
        for start in range(0, adjacency.shape[0], maps)
    )


def _filter_but_territory(policy: Any) -> Any:
    """The policy's DCBF settings but its territory: learners whose filters differ only in the
    territory their neglect bound covers still act in one stacked pass (:func:`_filtered_masks`)."""
    from dataclasses import replace

    config = policy.dcbf_config
    return replace(config, territory=()) if config.territory else config


def _filtered_masks(
    policies: Sequence[Any], pre: dict[str, th.Tensor], u_hat: th.Tensor, given: th.Tensor | None
) -> tuple[th.Tensor, th.Tensor | None]:
    """Every policy's DCBF mask ``(K * B, N)`` bool on its own ``B`` maps, and rule 8's decisions
    ``(K * B,)`` bool (``None`` when rule 8 is off).

    The filter has no parameters and decides each row alone, so policies with one filter take one
    call on all the maps; policies whose neglect bounds cover different territories take one call
    each, on their own rows.
    """
    first = policies[0]
    if all(p.dcbf_config == first.dcbf_config for p in policies):
        return first.filtered_masks(pre, u_hat, given)  # type: ignore[no-any-return]
    size = u_hat.shape[0] // len(policies)
    parts = []
    for k, policy in enumerate(policies):
        rows = slice(k * size, (k + 1) * size)
        own = {key: value[rows] for key, value in pre.items()}
        parts.append(policy.filtered_masks(own, u_hat[rows], None if given is None else given[rows]))
    masks = th.cat([mask for mask, _ in parts])
    forced = None if parts[0][1] is None else th.cat([f for _, f in parts])  # type: ignore[misc]
    return masks, forced


def _groups(stack: _Stack, x: th.Tensor) -> list[slice]:
    """The rows of ``x`` ``(K * B, ...)`` that belong to each policy (its ``B`` maps, in order)."""
    size = x.shape[0] // len(stack.policies)
    return [slice(k * size, (k + 1) * size) for k in range(len(stack.policies))]


def _per_policy(weights: th.Tensor, maps: int) -> th.Tensor:
    """Stacked weights ``(K, ...)`` repeated for each policy's ``maps`` maps: ``(K * maps, ...)``."""
    return weights if maps == 1 else weights.repeat_interleave(maps, dim=0)


def _first_weight(policy: DCBFActorCriticPolicy) -> th.Tensor:
    """The weight ``(w, d + h)`` of the actor body's first layer."""
    first: nn.Linear = policy.actor_body[0]  # type: ignore[assignment]
    return first.weight


def _per_map(stack: _Stack, name: str, x: th.Tensor) -> th.Tensor:
    """The linear layer ``name`` of each policy on its own maps: ``(K * B, N, d) -> (K * B, N, out)``,
    each on a fresh copy of its ``B`` maps' rows, as the serial path's input is."""
    return th.cat(
        [p.get_submodule(name)(x[rows].clone()) for p, rows in zip(stack.policies, _groups(stack, x))]
    )


def _activation(layer: nn.Module, x: th.Tensor, n: int, policies: int | None = None) -> th.Tensor:
    """``layer`` on ``x`` ``(K * B, N, d)``: batched where each policy's maps round as alone, else
    policy by policy (see the module docstring: whole blocks of :data:`TAIL_FREE`, and one thread
    at this size). ``policies``: ``K`` (default: one map per policy)."""
    if isinstance(layer, _TRANSCENDENTAL) and (
        (n * x.shape[-1]) % TAIL_FREE or (th.get_num_threads() > 1 and x.numel() > _ONE_THREAD_ELEMENTS)
    ):
        size = x.shape[0] // (policies or x.shape[0])
        return th.cat([layer(x[start : start + size].clone()) for start in range(0, x.shape[0], size)])
    return layer(x)  # type: ignore[no-any-return]


__all__ = ["TAIL_FREE", "RolloutHeads", "StackedInference", "stack_problem"]
