"""A whole team's forward pass at once: the learners' own policy code, mapped over their parameters.

A deployed team acts with one small forward pass per agent per step, and a training team's rollout
step runs one per learner: each a few hundred small tensor operations, so the time goes to
per-operation overhead rather than arithmetic. When the learners' policies share one architecture
(always, for a team built from one config), their parameters can be stacked along a leading axis
(``torch.func.stack_module_state``) and the policy's own methods mapped over that axis with
``torch.func.vmap`` and ``torch.func.functional_call``: every operation then runs once for the
``K`` learners, each learner's maps with its own weights. No layer is written twice: the GAT, the
estimator, the actor, the critic and ``advice_prior`` are the policy's code, and the parameters
are found by the module tree, not by name.

What has no parameters runs on the ``K * B`` maps directly, through the policy's own functions:
SB3's preprocessing, the positional encodings and attention masks of the maps' adjacencies, the
DCBF filter (policy by policy where the learners' neglect bounds cover different territories), and
the draw of a sampled action (policy by policy, in the team's order, each on its own row at its own
temperature, so torch's generator is consumed as one pass per agent consumes it).

Nothing is shared but the arithmetic: agent ``k``'s action depends only on its own observation and
its own learner's parameters. The batched kernels need not round as a single learner's do, so the
logits may differ from one pass per agent in the last bits (``tests/test_team_forward.py`` compares
the actions on whole episodes, and a short training run's parameters).

The pass covers the configurations the package trains by default; it returns ``None`` (the caller
then runs one pass per agent) for policies of other classes, policies that differ in more than
their parameters and DCBF territory, or steps it cannot map without data-dependent branches: a
batch the dense attention kernel would not run (:func:`~sb3_pm.policies.attention.use_dense`), one
large enough for the chunked attention kernel or the estimator's row gathering, ``actor_nodes:
allowed``, ``derived_features`` or ``extra_attention``. :func:`team_problem` says why.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any, NamedTuple

import numpy as np
import torch as th
from torch import nn
from torch.func import functional_call, vmap

from sb3_pm.policies.dcbf import territory_mask
from sb3_pm.policies.attention import attention_bias, use_chunked, use_dense
from sb3_pm.policies.estimator import GATHER_MIN_ROWS
from sb3_pm.policies.extractor import GATFeaturesExtractor
from sb3_pm.policies.policy import MAP_KEYS, DCBFActorCriticPolicy, masked_mode

#: Constructor parameters that do not change what a policy computes when it acts.
_NOT_ARCHITECTURE = ("lr_schedule", "optimizer_class", "optimizer_kwargs", "estimator_lr", "neglect_territory")


class RolloutHeads(NamedTuple):
    """One learner's rollout step from the team's pass (:meth:`TeamForward.rollout_heads`)."""

    logits: th.Tensor  #: ``(B, N)``
    values: th.Tensor  #: ``(B, 1)``
    masks: th.Tensor  #: ``(B, N)`` bool, the DCBF masks
    forced: th.Tensor | None  #: ``(B,)`` bool, where rule 8 forced the mask (``None``: rule 8 off)


def team_problem(policies: Sequence[Any]) -> str | None:
    """Why ``policies`` cannot act as one team pass whatever their maps, or ``None`` if they can."""
    if not policies:
        return "no policies"
    if any(type(p) is not DCBFActorCriticPolicy for p in policies):
        return "not every policy is a DCBFActorCriticPolicy"
    first = policies[0]
    extractor: GATFeaturesExtractor = first.features_extractor
    if first.actor_nodes != "all":
        return "actor_nodes: allowed picks nodes by the mask (data-dependent)"
    if extractor.backend == "sparse":
        return "gat_backend: sparse runs the sparse kernel on every map"
    if extractor.derived_features:
        return "derived_features search hop distances per map (data-dependent)"
    if extractor.extra_gat is not None:
        return "extra_attention is not mapped over learners"
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


class _Calls(nn.Module):
    """Runs its policy's own methods: ``functional_call`` on it swaps the policy's parameters for
    one learner's slice of the stacked ones.

    The one-unit output layers (the estimator's, ``action_net``, ``value_net``) are left out: they
    run as matrix-vector products, and a batched product over the learners rounds differently, so
    they run learner by learner on their own modules (:meth:`TeamForward._run`).
    """

    def __init__(self, policy: DCBFActorCriticPolicy) -> None:
        super().__init__()
        self.policy = policy

    def forward(self, stage: str, pre: dict[str, th.Tensor], *args: Any) -> Any:
        """``stage="estimator"``: the estimator's last hidden layer ``(B, N, w)`` on the ``B`` maps
        ``pre``; ``stage="heads"`` (args: ``û`` ``(B, N)``, ``values``): the actor body's output
        ``(B, N, pi_out)`` and with ``values`` the critic body's ``(B, vf_out)``, as
        :meth:`DCBFActorCriticPolicy._heads` computes them before its output layers."""
        policy = self.policy
        if stage == "estimator":
            assert policy.estimator is not None
            return policy.estimator.last_hidden(pre["nodes"])
        u_hat, values = args
        embeddings, own = policy._node_inputs(pre, u_hat)
        actor = policy._actor_hidden(embeddings, own)
        return (actor, policy._critic_hidden(embeddings, own)) if values else (actor,)


class TeamForward:
    """Every learner's forward pass as one pass over the stacked parameters (module docstring).

    Remembers, for the last list of policies it served, whether they can act as one pass, their
    parameter tensors, and a copy of the first policy whose module tree the stacked parameters run
    through (a copy, so that a learner's own modules are never touched, even while it trains in
    another thread). The parameters' values are stacked anew on every call.
    """

    def __init__(self) -> None:
        self._policies: list[Any] = []  # held so that their ids stay theirs
        self._problem: str | None = None
        self._calls: _Calls | None = None
        #: per stage of :meth:`_Calls.forward`, the parameters it reads: (name in the copy, every
        #: policy's tensor of it)
        self._sources: dict[str, list[tuple[str, list[th.Tensor]]]] = {}
        #: (adjacencies, encodings, attention masks) of the last call: a map's known adjacency
        #: changes only when its agent discovers an edge, so most steps reuse them
        self._graph_cache: tuple[th.Tensor, th.Tensor | None, th.Tensor] | None = None
        #: why the last call returned ``None`` (``None``: it did not)
        self.refusal: str | None = None

    # ------------------------------------------------------------ entry points
    def actions(
        self, policies: Sequence[Any], observations: Sequence[Mapping[str, Any]], deterministic: bool
    ) -> np.ndarray | None:
        """The action of ``policies[k]`` on ``observations[k]`` for every ``k``, as
        ``policy.predict(obs, deterministic, action_masks=obs["action_mask"])`` gives it, one
        policy after another (sampled ones drawn in that order); counts rule 8's decisions.
        ``None`` where this step must run one pass per policy.

        Shapes:
            - observations: ``K`` mental-map observations (numpy), one map each
            - output: ``(K,)`` int64
        """
        result = self._run(policies, observations, None)
        if result is None:
            return None
        logits, _, masks, forced = result
        if forced is not None:
            for k, policy in enumerate(policies):
                policy.count_forced(forced[k : k + 1])
        if deterministic:
            return masked_mode(logits, masks).cpu().numpy()
        actions = np.empty(len(policies), dtype=np.int64)
        with th.no_grad():
            for k, policy in enumerate(policies):  # the (1, N) row one pass would draw from, its own draw
                actions[k] = int(policy.draw(logits[k : k + 1], masks[k : k + 1]).reshape(-1)[0])
        return actions

    def rollout_heads(
        self, policies: Sequence[Any], observations: Sequence[Mapping[str, Any]]
    ) -> list[RolloutHeads] | None:
        """Every learner's :meth:`~sb3_pm.policies.DCBFActorCriticPolicy.rollout_heads` on its own
        batch of maps (a learner's ``VecEnv`` observation), with rule 8's decisions that call would
        count (counted by the caller, when a learner takes its result); ``None`` where this step
        must run one pass per learner.

        Shapes:
            - observations: ``K`` observations (numpy dicts), each ``(B, ...)`` per key
            - output: per learner, logits ``(B, N)``, values ``(B, 1)``, masks ``(B, N)`` bool and
              rule 8's decisions ``(B,)`` bool (``None`` when rule 8 is off)
        """
        if not observations or not isinstance(observations[0], Mapping) or "nodes" not in observations[0]:
            self.refusal = "the observations are not mental maps"
            return None
        result = self._run(policies, observations, int(np.shape(observations[0]["nodes"])[0]))
        if result is None:
            return None
        logits, values, masks, forced = result
        assert values is not None
        return [
            RolloutHeads(logits[rows], values[rows], masks[rows], None if forced is None else forced[rows])
            for rows in _groups(len(policies), masks.shape[0])
        ]

    def problem(self, policies: Sequence[Any]) -> str | None:
        """:func:`team_problem`, remembered for the same policy objects (whose architecture does
        not change); a new list also gets a new copy to run the stacked parameters through."""
        if len(policies) != len(self._policies) or any(a is not b for a, b in zip(policies, self._policies)):
            self._policies, self._problem = list(policies), team_problem(policies)
            self._calls, self._graph_cache = None, None
            if self._problem is None:
                self._calls = _Calls(copy.deepcopy(policies[0])).eval()
                self._sources = _stage_sources(self._calls, policies)
        return self._problem

    # ------------------------------------------------------------------ the pass
    def _run(
        self, policies: Sequence[Any], observations: Sequence[Mapping[str, Any]], maps: int | None
    ) -> tuple[th.Tensor, th.Tensor | None, th.Tensor, th.Tensor | None] | None:
        """Every policy's logits ``(K * B, N)``, values ``(K * B, 1)`` (rollouts only, else
        ``None``), DCBF masks ``(K * B, N)`` bool and rule 8's decisions ``(K * B,)`` bool
        (``None`` when rule 8 is off), policy ``k``'s ``B`` maps in rows ``k * B`` to
        ``(k + 1) * B - 1``: for ``predict`` (``maps=None``: one map each, the observation's
        ``action_mask`` intersected with the filter's) or a rollout step (``maps`` each, the
        filter's masks alone). ``None``: refused (:attr:`refusal` says why)."""
        self.refusal = None
        if len(policies) != len(observations):
            self.refusal = "not one observation per policy"
            return None
        self.refusal = self.problem(policies)
        if self.refusal is not None:
            return None
        first: DCBFActorCriticPolicy = policies[0]
        batch = 1 if maps is None else maps
        space = first.observation_space
        arrays = {}
        for key in MAP_KEYS:
            shape = space[key].shape  # type: ignore[index]
            values = [np.asarray(obs[key]) for obs in observations]
            allowed = (shape, (1, *shape)) if maps is None else ((maps, *shape),)
            if any(v.shape not in allowed for v in values):
                self.refusal = "an observation is not of the observation space's shape"
                return None  # one pass per policy raises SB3's error for it
            arrays[key] = th.as_tensor(np.concatenate([v.reshape(batch, *shape) for v in values]))
        arrays = {key: value.to(first.device) for key, value in arrays.items()}
        self.refusal = _shape_problem(first, arrays["adjacency"], batch)
        if self.refusal is not None:
            return None
        for policy in policies:
            policy.set_training_mode(False)  # as SB3's predict and collect_rollouts do
        groups = _groups(len(policies), len(policies) * batch)
        with th.no_grad():
            pre = first._preprocess(arrays)
            pre.update(self._graph_inputs(first, pre["adjacency"]))
            params = {
                stage: {name: th.stack(group) for name, group in sources}
                for stage, sources in self._sources.items()
            }
            if first.estimator is None:
                u_hat = first.uncertainty(pre)  # the maps' own u: no parameters
            else:
                hidden = self._mapped(params["estimator"], "estimator", {"nodes": pre["nodes"]})
                u_hat = th.cat(
                    [
                        p.estimator.scaled(p.estimator.normalized_from_hidden(hidden[k].clone(), pre["nodes"][rows]))
                        for k, (p, rows) in enumerate(zip(policies, groups))
                    ]
                )
            rollout = maps is not None
            read = ("nodes", "adjacency", "position_index", "attention_bias", "encoding")
            inputs = {key: pre[key] for key in read if key in pre}  # what the extractor and heads read
            bodies = self._mapped(params["heads"], "heads", inputs, u_hat, rollout)
            logits = th.cat(
                [
                    p._with_advice(p._actor_output(bodies[0][k].clone()), {"nodes": pre["nodes"][rows]})
                    for k, (p, rows) in enumerate(zip(policies, groups))
                ]
            )
            values = th.cat([p.value_net(bodies[1][k].clone()) for k, p in enumerate(policies)]) if rollout else None
            masks, forced = _filtered_masks(policies, pre, u_hat, None if rollout else arrays["action_mask"])
        return logits, values, masks, forced

    def _graph_inputs(self, policy: DCBFActorCriticPolicy, adjacency: th.Tensor) -> dict[str, th.Tensor]:
        """The dense kernel's inputs of every map (:meth:`GATFeaturesExtractor.node_embeddings`),
        parameter-free: computed on all ``K * B`` adjacencies ``(K * B, N, N)`` at once, and reused
        while they are unchanged."""
        cached = self._graph_cache
        if cached is None or cached[0].shape != adjacency.shape or not th.equal(cached[0], adjacency):
            extractor: GATFeaturesExtractor = policy.features_extractor  # type: ignore[assignment]
            cached = (adjacency.clone(), extractor.encoding(adjacency), attention_bias(adjacency))
            self._graph_cache = cached
        inputs = {"attention_bias": cached[2]}
        if cached[1] is not None:
            inputs["encoding"] = cached[1]
        return inputs

    def _mapped(self, params: dict[str, th.Tensor], stage: str, pre: dict[str, th.Tensor], *args: Any) -> Any:
        """:meth:`_Calls.forward` of every policy on its own rows of ``pre`` (``(K * B, ...)`` per
        key, and of a tensor among ``args``), with its own parameters ``params`` (``(K, ...)``
        each): ``(K, B, ...)`` outputs."""
        calls = self._calls
        assert calls is not None
        k = next(iter(params.values())).shape[0]
        split = {key: value.reshape(k, -1, *value.shape[1:]) for key, value in pre.items()}
        tensors = tuple(a.reshape(k, -1, *a.shape[1:]) for a in args if isinstance(a, th.Tensor))
        flags = tuple(a for a in args if not isinstance(a, th.Tensor))

        def one(p: dict[str, th.Tensor], maps: dict[str, th.Tensor], *rest: th.Tensor) -> Any:
            # Buffers are the observation space's highs, the same in every policy (_signature).
            return functional_call(calls, p, (stage, maps, *rest, *flags), tie_weights=False, strict=False)

        return vmap(one)(params, split, *tensors)


def _stage_sources(calls: _Calls, policies: Sequence[Any]) -> dict[str, list[tuple[str, list[th.Tensor]]]]:
    """Per stage of :meth:`_Calls.forward`, the parameters it reads, each as its name in ``calls``
    and every policy's tensor of it, found once (walking the module trees on every step cost more
    than the pass's arithmetic; the values are read anew on every call). Each stage is given only
    its own: ``functional_call`` swaps every tensor it is given, twice per call."""
    policy = calls.policy
    outputs = [policy.action_net, policy.value_net]
    estimator = {id(p) for p in policy.estimator.parameters()} if policy.estimator is not None else set()
    if policy.estimator is not None:
        outputs.append(policy.estimator.net[-1])
    apart = {id(p) for module in outputs for p in module.parameters()}  # run policy by policy
    copied = [id(p) for p in calls.parameters()]
    owned = [list(p.parameters()) for p in policies]  # the same order as the copy's (one architecture)
    sources: dict[str, list[tuple[str, list[th.Tensor]]]] = {"estimator": [], "heads": []}
    for index, (name, parameter) in enumerate(calls.named_parameters()):
        if id(parameter) in apart:
            continue
        stage = "estimator" if id(parameter) in estimator else "heads"
        sources[stage].append((name, [tensors[index] for tensors in owned]))
    assert len(copied) == len(owned[0])
    return sources


def _groups(k: int, rows: int) -> list[slice]:
    """Each of ``k`` policies' rows among ``rows`` (its ``B`` maps, in order)."""
    size = rows // k
    return [slice(i * size, (i + 1) * size) for i in range(k)]


def _shape_problem(policy: DCBFActorCriticPolicy, adjacency: th.Tensor, maps: int) -> str | None:
    """Why ``maps`` maps per policy (adjacencies ``(K * maps, N, N)``) cannot be mapped over the
    learners: one pass per policy would take a kernel with data-dependent branches."""
    extractor: GATFeaturesExtractor = policy.features_extractor  # type: ignore[assignment]
    n = adjacency.shape[-1]
    for start in range(0, adjacency.shape[0], maps):
        if not use_dense(adjacency[start : start + maps], extractor.backend):
            return "a policy's maps would take the sparse attention kernel"
    if any(use_chunked(maps, int(layer.heads), n, adjacency.device.type == "cpu") for layer in extractor.gat):
        return f"{maps} maps of {n} nodes take the chunked attention kernel"
    if policy.estimator is not None and maps * n >= GATHER_MIN_ROWS:
        return f"{maps} maps of {n} nodes take the estimator's row gathering"
    return None


def _filtered_masks(
    policies: Sequence[Any], pre: dict[str, th.Tensor], u_hat: th.Tensor, given: th.Tensor | None
) -> tuple[th.Tensor, th.Tensor | None]:
    """Every policy's DCBF masks ``(K * B, N)`` bool on its own ``B`` maps, and rule 8's decisions
    ``(K * B,)`` bool (``None`` when rule 8 is off).

    The filter has no parameters and decides each map alone, and the policies' filters differ at
    most in the territory their neglect bounds cover (:func:`team_problem`): one call on all the
    maps, each map with its own policy's territory.
    """
    first = policies[0]
    config = first.dcbf_config
    if config.neglect_bound is not None and config.neglect_scope == "territory":
        n, size = u_hat.shape[1], u_hat.shape[0] // len(policies)
        pre = {
            **pre,
            "neglect_territory": th.cat(
                [territory_mask(p.dcbf_config.territory, size, n, u_hat.device) for p in policies]
            ),
        }
    return first.filtered_masks(pre, u_hat, given)  # type: ignore[no-any-return]


__all__ = ["RolloutHeads", "TeamForward", "team_problem"]
