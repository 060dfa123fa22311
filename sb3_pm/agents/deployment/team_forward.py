"""A whole team's forward pass at once: the learners' own policy code, mapped over their parameters.

A deployed team acts with one small forward pass per agent per step, and a training team's rollout
step runs one per learner: a few hundred small tensor operations each, so the time goes to
per-operation overhead rather than arithmetic. The learners' policies share one architecture
(always, for a team built from one config), so their parameters are stacked along a leading axis
and the policy's own methods run once for all ``K`` learners, through ``torch.func.vmap`` over
``torch.func.functional_call`` on a module tree built like theirs. Nothing of the network is
written twice (the GAT, the estimator, the actor, the critic and ``advice_prior`` are the policy's
code), and parameters are matched by the module tree, never by name. The tensors to stack are found
once per list of policies (``torch.func.stack_module_state`` walks the module trees on every call,
which cost as much as the arithmetic) and their values stacked anew on every call.

What has no parameters runs on the ``K * B`` maps at once, through the policy's own functions:
SB3's preprocessing, the encodings and attention masks, and the DCBF filter (each map with its
own learner's territory). Sampled actions are drawn learner by learner, in the team's order, each
from its own row at its own temperature, as one pass per agent draws them.

**Bit for bit.** A batched product over the learners rounds as each learner's own product except
where that one runs as a matrix-vector kernel: products with one output unit (the estimator's
output layer, ``action_net``, ``value_net``) or with one row per map (the actor's product with
the own node's embedding, the critic). Those run learner by learner, on each policy's own modules
and methods; so do the few elementwise steps between them. An elementwise activation rounds alike
where each learner's part fills whole blocks of its vector loop and one thread runs it
(:mod:`sb3_pm.agents.deployment.team_checks`). So the logits, values and masks are one pass per agent's, bit
for bit, and a seeded training run ends with the same parameters (``tests/test_team_forward.py``,
``tests/test_rollout_batching.py``). On large graphs the most likely actions are decided from the
allowed nodes' logits alone where that gives the same actions (:mod:`sb3_pm.agents.deployment.allowed_nodes`:
the policy's own actor on those nodes' rows of its inputs).

It returns ``None`` (the caller then runs one pass per agent) for policies that
:func:`~sb3_pm.agents.deployment.team_checks.team_problem` refuses (other classes, off the CPU, differing in
more than their parameters and territory, ``gat_backend: sparse``), and for steps whose per-agent kernels take
data-dependent branches or whose activations would round otherwise (:attr:`TeamForward.refusal`
says why).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any, NamedTuple

import numpy as np
import torch as th
from torch import nn
from torch.func import functional_call, vmap

from sb3_pm.agents.deployment.allowed_nodes import allowed_actions, applies
from sb3_pm.agents.deployment.team_checks import shape_problem, team_problem
from sb3_pm.policies.attention import attention_bias
from sb3_pm.policies.dcbf import territory_mask
from sb3_pm.policies.extractor import GATFeaturesExtractor
from sb3_pm.policies.heads import masked_mode
from sb3_pm.policies.policy import MAP_KEYS, DCBFActorCriticPolicy
from sb3_pm.policies.visit_deadline import VISIT_AGE, VISIT_TARGETS


class _Pass(NamedTuple):
    """What :meth:`TeamForward._run` computed, ``K * B`` maps in all."""

    logits: th.Tensor | None  #: ``(K * B, N)`` (``None``: ``actions`` decided from fewer)
    values: th.Tensor | None  #: ``(K * B, 1)``, rollouts only
    masks: th.Tensor  #: ``(K * B, N)`` bool, the DCBF masks
    forced: th.Tensor | None  #: ``(K * B,)`` bool, rule 8's decisions (``None``: rule 8 off)
    actions: np.ndarray | None  #: ``(K,)`` the most likely actions, if decided from allowed nodes


class RolloutHeads(NamedTuple):
    """One learner's rollout step from the team's pass (:meth:`TeamForward.rollout_heads`)."""

    logits: th.Tensor  #: ``(B, N)``
    values: th.Tensor  #: ``(B, 1)``
    masks: th.Tensor  #: ``(B, N)`` bool, the DCBF masks
    forced: th.Tensor | None  #: ``(B,)`` bool, where rule 8 forced the mask (``None``: rule 8 off)


class _Calls(nn.Module):
    """Runs its policy's own methods: ``functional_call`` on it swaps the policy's parameters for
    one learner's slice of the stacked ones. The matrix-vector products (module docstring) are not
    among them: :meth:`TeamForward._run` runs those learner by learner."""

    def __init__(self, policy: DCBFActorCriticPolicy) -> None:
        super().__init__()
        self.policy = policy

    def forward(self, stage: str, pre: dict[str, th.Tensor], *args: th.Tensor) -> Any:
        """On the ``B`` maps ``pre``: ``stage="embed"``, the GAT's node embeddings ``(B, N, h)``
        and, with an estimator, its last hidden layer ``(B, N, w)``; ``stage="actor"`` (args: the
        heads' per-node inputs ``(B, N, d)``, the own node's embedding ``(B, h)`` and
        :meth:`~DCBFActorCriticPolicy._actor_own_term` ``(B, w)``), the actor body's output
        ``(B, N, pi_out)``."""
        policy = self.policy
        if stage == "actor":
            embeddings, own, own_term = args
            return policy._actor_hidden(embeddings, own, own_term=own_term)
        extractor: GATFeaturesExtractor = policy.features_extractor  # type: ignore[assignment]
        embeddings = extractor.node_embeddings(pre)
        if policy.estimator is None:
            return (embeddings,)
        return embeddings, policy.estimator.last_hidden(pre["nodes"])


class TeamForward:
    """Every learner's forward pass as one pass over the stacked parameters (module docstring).

    Remembers, for the last list of policies it served, whether they can act as one pass, their
    parameter tensors, and a policy built like the first whose module tree the stacked parameters
    run through (not a learner's own, which may be training in another thread)."""

    def __init__(self) -> None:
        self._policies: list[Any] = []  # held so that their ids stay theirs
        self._problem: str | None = None
        self._calls: _Calls | None = None
        #: per stage of :meth:`_Calls.forward`, the parameters it reads: (name in the copy, every
        #: policy's tensor of it)
        self._sources: dict[str, list[tuple[str, list[th.Tensor]]]] = {}
        #: (adjacencies, encodings, attention masks) of the last call: a known map changes only
        #: when its agent discovers an edge
        self._graph_cache: tuple[th.Tensor, th.Tensor | None, th.Tensor] | None = None
        #: why the last call returned ``None`` (``None``: it did not)
        self.refusal: str | None = None
        #: decide most likely actions from the allowed nodes' logits where that gives the same
        #: actions (:mod:`sb3_pm.agents.deployment.allowed_nodes`); ``False``: always every node's logit
        self.allowed_only = True
        #: most likely steps decided from the allowed nodes' logits, and from every node's
        self.counts = {"allowed": 0, "all": 0}

    # ------------------------------------------------------------ entry points
    def actions(
        self, policies: Sequence[Any], observations: Sequence[Mapping[str, Any]], deterministic: bool
    ) -> np.ndarray | None:
        """``(K,)`` int64: the action of ``policies[k]`` on the mental-map observation
        ``observations[k]`` (numpy, one map) for every ``k``, as ``policy.predict(obs,
        deterministic, action_masks=obs["action_mask"])`` gives it one policy after another
        (sampled ones drawn in that order); counts rule 8's decisions. ``None``: this step must run
        one pass per policy."""
        result = self._acting_pass(policies, observations, deterministic and self.allowed_only)
        if result is None:
            return None
        if result.actions is not None:
            return result.actions
        logits, masks = result.logits, result.masks
        assert logits is not None
        if deterministic:
            return masked_mode(logits, masks).cpu().numpy()
        actions = np.empty(len(policies), dtype=np.int64)
        with th.no_grad():
            for k, policy in enumerate(policies):  # the (1, N) row one pass would draw from, its own draw
                actions[k] = int(policy.draw(logits[k : k + 1], masks[k : k + 1]).reshape(-1)[0])
        return actions

    def logits(
        self, policies: Sequence[Any], observations: Sequence[Mapping[str, Any]]
    ) -> tuple[th.Tensor, th.Tensor] | None:
        """What :meth:`actions` decides from: every policy's logits ``(K, N)`` on its own
        observation and its DCBF mask ``(K, N)`` bool (the observation's ``action_mask``
        intersected with the filter's), counting rule 8's decisions; ``None`` as :meth:`actions`."""
        result = self._acting_pass(policies, observations, False)
        return None if result is None or result.logits is None else (result.logits, result.masks)

    def _acting_pass(
        self, policies: Sequence[Any], observations: Sequence[Mapping[str, Any]], allowed_only: bool
    ) -> _Pass | None:
        """:meth:`_run` for ``predict_dict``, counting rule 8's decisions."""
        result = self._run(policies, observations, None, allowed_only)
        if result is not None and result.forced is not None:
            for k, policy in enumerate(policies):
                policy.count_forced(result.forced[k : k + 1])
        return result

    def rollout_heads(
        self, policies: Sequence[Any], observations: Sequence[Mapping[str, Any]]
    ) -> list[RolloutHeads] | None:
        """Every learner's :meth:`~sb3_pm.policies.DCBFActorCriticPolicy.rollout_heads` on its own
        ``VecEnv`` observation (numpy, ``(B, ...)`` per key): logits ``(B, N)``, values ``(B, 1)``,
        masks ``(B, N)`` bool, and rule 8's decisions ``(B,)`` bool that call would count (``None``
        with rule 8 off; the caller counts them when a learner takes its result). ``None``: this
        step must run one pass per learner."""
        if not observations or not isinstance(observations[0], Mapping) or "nodes" not in observations[0]:
            self.refusal = "the observations are not mental maps"
            return None
        result = self._run(policies, observations, int(np.shape(observations[0]["nodes"])[0]))
        if result is None:
            return None
        logits, values, masks, forced, _ = result
        assert logits is not None and values is not None
        return [
            RolloutHeads(logits[rows], values[rows], masks[rows], None if forced is None else forced[rows])
            for rows in _groups(len(policies), masks.shape[0])
        ]

    def problem(self, policies: Sequence[Any]) -> str | None:
        """:func:`team_problem`, remembered for the same policy objects, or a difference in their
        filter settings (deployment may change them at any time)."""
        if len(policies) != len(self._policies) or any(a is not b for a, b in zip(policies, self._policies)):
            self._policies, self._problem = list(policies), team_problem(policies)
            self._calls, self._graph_cache = None, None
            if self._problem is None:
                self._calls = _Calls(_skeleton(policies[0])).eval()
                self._sources = _stage_sources(self._calls, policies)
        if self._problem is None:
            settings = replace(policies[0].dcbf_config, territory=())
            if any(replace(p.dcbf_config, territory=()) != settings for p in policies):
                return "the policies' DCBF filter settings differ"
        return self._problem

    # ------------------------------------------------------------------ the pass
    def _run(
        self,
        policies: Sequence[Any],
        observations: Sequence[Mapping[str, Any]],
        maps: int | None,
        allowed_only: bool = False,
    ) -> _Pass | None:
        """The pass (:class:`_Pass`; policy ``k``'s ``B`` maps in rows ``k * B`` to
        ``(k + 1) * B - 1``) for ``predict_dict`` (``maps=None``: one map each, the observation's
        ``action_mask`` intersected with the filter's) or a rollout step (``maps`` each, the
        filter's masks alone); ``allowed_only``: the most likely actions from the allowed nodes'
        logits where they decide them. ``None``: refused (:attr:`refusal` says why)."""
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
        if "adjacency" not in space.spaces:  # type: ignore[attr-defined]
            # The mapped pass runs the dense kernel on each map's adjacency; an edges-layout map
            # takes the sparse kernel on its edge list, one pass per policy.
            self.refusal = "maps in the env's edges layout take one pass per policy"
            return None
        arrays = {}
        for key in MAP_KEYS:
            shape = space[key].shape  # type: ignore[index]
            given = [np.asarray(obs[key]) for obs in observations]
            allowed = (shape, (1, *shape)) if maps is None else ((maps, *shape),)
            if any(v.shape not in allowed for v in given):
                self.refusal = "an observation is not of the observation space's shape"
                return None  # one pass per policy raises SB3's error for it
            stacked = np.concatenate([v.reshape(batch, *shape) for v in given])
            arrays[key] = th.as_tensor(stacked).to(first.device)
        self.refusal = shape_problem(first, arrays["adjacency"], batch)
        if self.refusal is not None:
            return None
        for policy in policies:
            policy.set_training_mode(False)  # as SB3's predict and collect_rollouts do
        groups = _groups(len(policies), len(policies) * batch)
        rollout = maps is not None
        with th.no_grad():
            pre = first._preprocess(arrays)
            pre.update(self._graph_inputs(first, pre["adjacency"]))
            params = {
                stage: {name: th.stack(group) for name, group in sources}
                for stage, sources in self._sources.items()
            }
            read = ("nodes", "adjacency", "position_index", "attention_bias", "encoding")
            inputs = {key: pre[key] for key in read if key in pre}  # what the extractor and heads read
            embedded = self._mapped(params["embed"], "embed", inputs)
            own_maps = [{key: value[rows] for key, value in pre.items()} for rows in groups]
            parts: list[list[th.Tensor]] = [[], [], [], [], []]  # û, heads' inputs, own, own term, values
            for k, (policy, maps_k) in enumerate(zip(policies, own_maps)):
                estimator = policy.estimator
                if estimator is None:
                    u_hat = policy.uncertainty(maps_k)  # the maps' own u: no parameters
                else:
                    hidden_k = embedded[1][k].clone()  # a learner's own tensor, as alone
                    u_hat = estimator.scaled(estimator.normalized_from_hidden(hidden_k, maps_k["nodes"]))
                per_node, own = policy._with_estimate(embedded[0][k].clone(), maps_k, u_hat)
                row = [u_hat, per_node, own, policy._actor_own_term(own)]
                row += [policy._value(per_node, own)] if rollout else []
                for part, tensor in zip(parts, row):
                    part.append(tensor)
            u_hats, per_nodes, owns, own_terms = (th.cat(part) for part in parts[:4])
            values = th.cat(parts[4]) if rollout else None
            masks, forced = _filtered_masks(policies, pre, u_hats, None if rollout else arrays["action_mask"])
            if allowed_only and applies(first):
                actor = params["actor"]  # the actor stage on other rows of the heads' inputs

                def body(rows: th.Tensor) -> th.Tensor:
                    return self._mapped(actor, "actor", {}, rows, owns, own_terms)[:, 0]  # type: ignore[no-any-return]

                chosen = allowed_actions(body, policies, per_nodes, masks)
                self.counts["allowed" if chosen is not None else "all"] += 1
                if chosen is not None:
                    return _Pass(None, None, masks, forced, chosen)
            hidden = self._mapped(params["actor"], "actor", {}, per_nodes, owns, own_terms)
            logits = th.cat(
                [
                    policy._with_advice(policy._actor_output(hidden[k].clone()), maps_k)
                    for k, (policy, maps_k) in enumerate(zip(policies, own_maps))
                ]
            )
        return _Pass(logits, values, masks, forced, None)

    def _graph_inputs(self, policy: DCBFActorCriticPolicy, adjacency: th.Tensor) -> dict[str, th.Tensor]:
        """The dense kernel's inputs of the adjacencies ``(K * B, N, N)``
        (:meth:`GATFeaturesExtractor.node_embeddings`), reused while they are unchanged."""
        cached = self._graph_cache
        if cached is None or cached[0].shape != adjacency.shape or not th.equal(cached[0], adjacency):
            extractor: GATFeaturesExtractor = policy.features_extractor  # type: ignore[assignment]
            cached = (adjacency.clone(), extractor.encoding(adjacency), attention_bias(adjacency))
            self._graph_cache = cached
        inputs = {"attention_bias": cached[2]}
        if cached[1] is not None:
            inputs["encoding"] = cached[1]
        return inputs

    def _mapped(
        self, params: dict[str, th.Tensor], stage: str, pre: dict[str, th.Tensor], *args: th.Tensor
    ) -> Any:
        """:meth:`_Calls.forward` of every policy on its own rows of ``pre`` and ``args``
        (``(K * B, ...)`` each), with its own parameters ``params`` (``(K, ...)`` each):
        ``(K, B, ...)`` outputs."""
        calls = self._calls
        assert calls is not None
        k = next(iter(params.values())).shape[0]  # every stage reads parameters
        split = {key: value.reshape(k, -1, *value.shape[1:]) for key, value in pre.items()}
        tensors = tuple(a.reshape(k, -1, *a.shape[1:]) for a in args)

        def one(p: dict[str, th.Tensor], maps: dict[str, th.Tensor], *rest: th.Tensor) -> Any:
            # Only the parameters are swapped: the buffers are the observation space's highs, the
            # same in every policy (team_checks._signature).
            return functional_call(calls, p, (stage, maps, *rest), tie_weights=False, strict=False)

        return vmap(one)(params, split, *tensors)


def _skeleton(policy: DCBFActorCriticPolicy) -> DCBFActorCriticPolicy:
    """A new policy built as ``policy`` was (its module tree, for the stacked parameters to run
    through), drawing nothing from torch's global generator, so training and sampling draw as they
    would without it."""
    with th.random.fork_rng(devices=[]):
        return type(policy)(**policy._get_constructor_parameters()).to(policy.device)


def _stage_sources(calls: _Calls, policies: Sequence[Any]) -> dict[str, list[tuple[str, list[th.Tensor]]]]:
    """Per stage of :meth:`_Calls.forward`, the parameters it reads, each as its name in ``calls``
    and every policy's tensor of it, found once (walking the module trees on every step cost more
    than the pass's arithmetic; the values are read anew on every call). Each stage is given only
    its own: ``functional_call`` swaps every tensor it is given, twice per call."""
    policy = calls.policy
    outputs: list[nn.Module] = [policy.action_net, policy.value_net, policy.critic_body]
    if policy.estimator is not None:
        outputs.append(policy.estimator.net[-1])
    apart = {id(p) for module in outputs for p in module.parameters()}  # run policy by policy
    owned = [list(p.parameters()) for p in policies]  # the same order as the copy's (one architecture)
    actor = {id(p) for p in policy.actor_body.parameters()}
    sources: dict[str, list[tuple[str, list[th.Tensor]]]] = {"embed": [], "actor": []}
    for index, (name, parameter) in enumerate(calls.named_parameters()):
        if id(parameter) in apart:
            continue
        stage = "actor" if id(parameter) in actor else "embed"
        sources[stage].append((name, [tensors[index] for tensors in owned]))
    return sources


def _groups(k: int, rows: int) -> list[slice]:
    """Each of ``k`` policies' rows among ``rows`` (its ``B`` maps, in order)."""
    return [slice(i * (rows // k), (i + 1) * (rows // k)) for i in range(k)]


def _filtered_masks(
    policies: Sequence[Any], pre: dict[str, th.Tensor], u_hat: th.Tensor, given: th.Tensor | None
) -> tuple[th.Tensor, th.Tensor | None]:
    """Every policy's DCBF masks ``(K * B, N)`` bool on its own ``B`` maps, and rule 8's decisions
    ``(K * B,)`` bool (``None`` when rule 8 is off): the filter has no parameters and decides each
    map alone, and the policies' filters differ at most in their territories (:meth:`TeamForward.problem`)."""
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
    if config.visit_deadline is not None and all(p.visit_inputs is not None for p in policies):
        # rule 12's memory: a policy holds its agents' rows in the team's order, and acts here
        # once per agent in that order, so its j-th appearance reads its j-th block of rows
        size, taken, parts = u_hat.shape[0] // len(policies), {}, []
        for policy in policies:
            j = taken[id(policy)] = taken.get(id(policy), -1) + 1
            parts.append([inputs[j * size : (j + 1) * size] for inputs in policy.visit_inputs])
        pre = {**pre, VISIT_TARGETS: th.cat([p[0] for p in parts]), VISIT_AGE: th.cat([p[1] for p in parts])}
    return first.filtered_masks(pre, u_hat, given)  # type: ignore[no-any-return]


__all__ = ["RolloutHeads", "TeamForward", "team_problem"]
