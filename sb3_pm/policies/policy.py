"""The DCBF actor-critic policy of one agent (docs/METHOD.md "Network of one agent", "DCBF safety filter").

Architecture, for a batch of ``B`` mental maps on ``N`` nodes:

* :class:`~sb3_pm.policies.extractor.GATFeaturesExtractor` -> node embeddings ``H`` ``(B, N, h)``;
* :class:`~sb3_pm.policies.estimator.StateEstimator` -> ``û`` ``(B, N)``, **detached** (computed
  under ``no_grad``), so PPO's loss never moves it; it has its own optimizer
  (:attr:`DCBFActorCriticPolicy.estimator_optimizer`) and the policy optimizer excludes it;
* actor: one MLP applied to every node with shared weights, input ``[H_m, û_m / u_max, H_φ]``
  -> one logit per node (``H_φ``, the own node's embedding, tells every node where the agent is;
  without it a shared per-node head could not express "move relative to me");
* critic: ``[mean_m [H_m, û_m / u_max], H_φ]`` -> MLP -> value;
* DCBF mask (:mod:`sb3_pm.policies.dcbf`) from ``û`` (or, with ``use_estimator=False``, the map's
  last observed ``u``), applied to the categorical distribution.

Where masks come from: :meth:`DCBFActorCriticPolicy.rollout_heads` (and ``forward_with_masks``,
which samples from it) returns the DCBF mask a rollout step samples with, which
:class:`~sb3_pm.ppo_dcbf.DCBFPPO` stores in the rollout buffer; ``train()`` passes the stored masks
back to :meth:`evaluate_actions`. Every entry point that receives no mask (``forward``,
``get_distribution``, ``predict``) computes the DCBF mask itself, so deployment is filtered
exactly like training; a mask given by the caller is intersected with it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from functools import partial
from itertools import islice
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from sb3_contrib.common.maskable.distributions import MaskableDistribution
from sb3_contrib.common.maskable.policies import MaskableActorCriticPolicy
from stable_baselines3.common.type_aliases import PyTorchObs, Schedule
from torch import nn

from sb3_pm.envs.mental_map import FEATURES, U
from sb3_pm.errors import InputError
from sb3_pm.policies.dcbf import DCBFConfig, check_bound_below_cap, dcbf_filter_from_map
from sb3_pm.policies.estimator import StateEstimator
from sb3_pm.policies.extractor import GATFeaturesExtractor
from sb3_pm.policies.sampling import check_temperature, tempered_logits

MAP_KEYS = ("nodes", "adjacency", "position", "dwell", "action_mask")
#: Logit given to masked-out actions, sb3-contrib's ``MaskableCategorical`` value.
_HUGE_NEG = th.tensor(-1e8)


def _mlp(in_dim: int, hidden: list[int], activation: type[nn.Module]) -> tuple[nn.Sequential, int]:
    layers: list[nn.Module] = []
    for width in hidden:
        layers += [nn.Linear(in_dim, width), activation()]
        in_dim = width
    return nn.Sequential(*layers), in_dim


def check_advice_prior(value: Any, observation_space: spaces.Dict) -> float:
    """``advice_prior`` as a float: finite, ``>= 0``, and positive only with a node column after the
    map's own (the env's ``advice_input``, which the team checks is on)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value) or value < 0:
        raise InputError(f"advice_prior must be a finite number >= 0, got {value!r}")
    columns = observation_space["nodes"].shape
    if value > 0 and (columns is None or columns[-1] <= len(FEATURES)):
        raise InputError(
            "advice_prior adds to the node the env's advice_input flags: it needs advice_input: true"
        )
    return float(value)


def check_advice_source(policies: Mapping[str, Any], env_kwargs: Mapping[str, Any]) -> None:
    """Refuse a policy's ``advice_prior`` unless the env appends the advice column: the policy
    adds it to the map's *last* column, which without ``advice_input`` is another feature (the
    territory's, with ``territory_input``). ``policies``: name -> policy (or anything else)."""
    if env_kwargs.get("advice_input") is True:
        return
    with_prior = [name for name, policy in policies.items() if getattr(policy, "advice_prior", 0.0)]
    if with_prior:
        raise InputError(
            f"advice_prior (set for {with_prior}) needs env_kwargs advice_input: true, "
            "whose column it adds to the logits"
        )


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


class DCBFActorCriticPolicy(MaskableActorCriticPolicy):
    """Masked actor-critic over a mental map, with a GAT encoder, a state estimator and a DCBF filter.

    :param observation_space: the map observation ``Dict`` of :mod:`sb3_pm.envs.persistent_monitoring`.
    :param action_space: ``Discrete(N)``.
    :param lr_schedule: learning-rate schedule of the actor-critic optimizer.
    :param net_arch: hidden sizes of the heads, ``dict(pi=[...], vf=[...])`` or one list for both
        (default ``dict(pi=[64, 64], vf=[64, 64])``).
    :param activation_fn: activation of the heads.
    :param ortho_init: orthogonal initialization of the heads (the GAT keeps PyG's glorot init).
    :param features_extractor_class: the graph encoder (default :class:`GATFeaturesExtractor`).
    :param features_extractor_kwargs: extra encoder kwargs; the explicit kwargs below win.
    :param use_dcbf: apply the DCBF filter (off: the mask is the reachable set).
    :param use_estimator: build the state estimator (off: no ``û`` input to the heads, and the
        filter uses the map's last observed ``u``).
    :param avoid_collisions: DCBF rule 6.
    :param freeze_steps: DCBF rule 5 (0 disables the freeze).
    :param eta: DCBF margin ``η``.
    :param gamma_threshold: DCBF activation threshold ``γ``.
    :param dcbf_barrier: DCBF rules 2-4 (off: the filter keeps only feasibility, the freeze and
        rule 6; see :mod:`sb3_pm.policies.dcbf`).
    :param neglect_bound: the DCBF's neglect bound ``B`` (rule 8, :mod:`sb3_pm.policies.neglect_bound`):
        a known target whose worst-case uncertainty could pass ``B`` before the agent arrives
        forces the next hop towards it. ``None`` (default) turns it off; it needs ``use_dcbf``.
    :param neglect_scope: which targets the bound covers, ``"known"``, ``"unserved"`` or
        ``"territory"`` (:class:`~sb3_pm.policies.dcbf.DCBFConfig`).
    :param neglect_territory: the agent's own targets, for ``neglect_scope="territory"``.
    :param laplacian: ``"rows"`` or ``"none"``.
    :param gat_heads: heads per GAT layer.
    :param hidden_dim: node embedding size ``h``.
    :param gat_layers: number of multi-head GAT layers.
    :param gat_backend: ``"auto"``, ``"dense"`` or ``"sparse"``.
    :param estimator_hidden: hidden sizes of the estimator MLP.
    :param estimator_lr: Adam learning rate of the estimator.
    :param estimator_epochs: passes over each rollout's pairs when fitting the estimator.
    :param estimator_batch_size: minibatch size (pairs) when fitting the estimator.
    :param advice_prior: a fixed number added to the logit of the node the map's last column
        flags, which is the env's ``advice_input`` (the territory rule's next move; the team
        refuses the option without it). ``0`` (default): no prior. With ``b > 0`` an untrained
        actor already takes the rule's move with probability ``e^b / (e^b + d)`` among ``d + 1``
        allowed nodes, and learning changes the actor only where leaving the rule pays.
    """

    def __init__(
        self,
        observation_space: spaces.Dict,
        action_space: spaces.Discrete,
        lr_schedule: Schedule,
        net_arch: list[int] | dict[str, list[int]] | None = None,
        activation_fn: type[nn.Module] = nn.Tanh,
        ortho_init: bool = True,
        features_extractor_class: type[GATFeaturesExtractor] = GATFeaturesExtractor,
        features_extractor_kwargs: dict[str, Any] | None = None,
        share_features_extractor: bool = True,
        normalize_images: bool = True,
        optimizer_class: type[th.optim.Optimizer] = th.optim.Adam,
        optimizer_kwargs: dict[str, Any] | None = None,
        use_dcbf: bool = True,
        use_estimator: bool = True,
        avoid_collisions: bool = False,
        freeze_steps: int = 10,
        eta: float = 0.1,
        gamma_threshold: float = 0.0,
        dcbf_barrier: bool = True,
        neglect_bound: float | None = None,
        neglect_scope: str = "known",
        neglect_territory: Sequence[int] = (),
        laplacian: str = "rows",
        gat_heads: int = 4,
        hidden_dim: int = 32,
        gat_layers: int = 2,
        gat_backend: str = "auto",
        estimator_hidden: list[int] | tuple[int, ...] = (64, 64),
        estimator_lr: float = 1e-3,
        estimator_epochs: int = 5,
        estimator_batch_size: int = 256,
        advice_prior: float = 0.0,
    ) -> None:
        if not isinstance(observation_space, spaces.Dict) or any(
            k not in observation_space.spaces for k in MAP_KEYS
        ):
            raise InputError(
                f"DCBFActorCriticPolicy needs the mental-map Dict observation with keys {MAP_KEYS}"
            )
        if not isinstance(action_space, spaces.Discrete):
            raise InputError(f"DCBFActorCriticPolicy needs a Discrete action space, got {action_space}")
        if not share_features_extractor:
            raise InputError("DCBFActorCriticPolicy shares its graph encoder between actor and critic")
        # Plain attributes are set before nn.Module.__init__ (allowed for non-tensors) because the
        # parent constructor calls our _build, which reads them.
        self.use_dcbf, self.use_estimator = bool(use_dcbf), bool(use_estimator)
        self.avoid_collisions = bool(avoid_collisions)
        self.advice_prior = check_advice_prior(advice_prior, observation_space)
        if neglect_bound is not None and not use_dcbf:
            raise InputError("neglect_bound is rule 8 of the DCBF filter: it needs use_dcbf=True")
        self.dcbf_config = DCBFConfig(
            eta,
            int(freeze_steps),
            bool(avoid_collisions),
            float(gamma_threshold),
            bool(dcbf_barrier),
            None if neglect_bound is None else float(neglect_bound),
            str(neglect_scope),
            tuple(int(node) for node in neglect_territory),
        )
        #: The filter as built from the constructor: a deployed team acts under it with its own
        #: settings on top (``DeploymentRule.set_filter``), and ``reset_filter`` restores it.
        self.trained_dcbf_config = self.dcbf_config
        #: Masks the filter computed with rule 8 (the neglect bound) on, and how many it forced: a
        #: diagnostic read by ``DeploymentRule.filter_activity()``, never saved. ``forced`` is summed
        #: as a tensor, so counting costs no device synchronisation per forward pass.
        self.filter_counts: dict[str, Any] = {"masks": 0, "forced": 0}
        self._sampling_temperature = 1.0
        self.estimator_hidden = [int(w) for w in estimator_hidden]
        self.estimator_lr, self.estimator_epochs = float(estimator_lr), int(estimator_epochs)
        self.estimator_batch_size = int(estimator_batch_size)
        self._encoder_kwargs = dict(
            laplacian=laplacian,
            gat_heads=gat_heads,
            hidden_dim=hidden_dim,
            gat_layers=gat_layers,
            backend=gat_backend,
        )
        # The encoder's settings are this policy's own arguments. The same key in
        # features_extractor_kwargs with another value used to be overwritten without a word
        # (hidden_dim: 64 there gave 32); now it is an error that names the argument to use.
        argument_for = {"backend": "gat_backend"}
        clash = sorted(
            key
            for key, value in (features_extractor_kwargs or {}).items()
            if key in self._encoder_kwargs and value != self._encoder_kwargs[key]
        )
        if clash:
            names = ", ".join(f"{key} (pass {argument_for.get(key, key)}=...)" for key in clash)
            raise InputError(
                f"features_extractor_kwargs sets {names}: DCBFActorCriticPolicy sets the graph encoder "
                "from its own arguments; give them as policy_kwargs instead"
            )
        features_extractor_kwargs = {**(features_extractor_kwargs or {}), **self._encoder_kwargs}
        if net_arch is None:
            net_arch = dict(pi=[64, 64], vf=[64, 64])
        super().__init__(
            observation_space,
            action_space,
            lr_schedule,
            net_arch=net_arch,
            activation_fn=activation_fn,
            ortho_init=ortho_init,
            features_extractor_class=features_extractor_class,
            features_extractor_kwargs=features_extractor_kwargs,
            share_features_extractor=True,
            normalize_images=normalize_images,
            optimizer_class=optimizer_class,
            optimizer_kwargs=optimizer_kwargs,
        )

    # ----------------------------------------------------------------- build
    def _build(self, lr_schedule: Schedule) -> None:
        """Build the estimator first, then the heads, then two optimizers over disjoint parameters."""
        nodes_space = self.observation_space["nodes"]  # type: ignore[index]
        self.n_nodes = int(nodes_space.shape[0])
        self.u_max = float(nodes_space.high[:, U].max())
        check_bound_below_cap(self.dcbf_config.neglect_bound, self.u_max)
        extractor: GATFeaturesExtractor = self.features_extractor  # type: ignore[assignment]
        hidden = extractor.hidden_dim
        self.estimator: StateEstimator | None = None
        if self.use_estimator:
            # every node column of the map, FEATURES and any the env appends (territory_input, advice_input)
            self.estimator = StateEstimator(
                int(extractor.inv_high.shape[-1]), self.u_max, extractor.inv_high, self.estimator_hidden
            )
        u_dim = 1 if self.use_estimator else 0
        if isinstance(self.net_arch, dict):
            pi_arch, vf_arch = list(self.net_arch.get("pi", [])), list(self.net_arch.get("vf", []))
        else:
            pi_arch = vf_arch = list(self.net_arch)
        self.actor_body, pi_out = _mlp(hidden + u_dim + hidden, pi_arch, self.activation_fn)
        self.action_net = nn.Linear(pi_out, 1)  # one logit per node, weights shared across nodes
        self.critic_body, vf_out = _mlp(hidden + u_dim + hidden, vf_arch, self.activation_fn)
        self.value_net = nn.Linear(vf_out, 1)
        if self.ortho_init:
            for module, gain in (
                (self.actor_body, np.sqrt(2)),
                (self.critic_body, np.sqrt(2)),
                (self.action_net, 0.01),
                (self.value_net, 1.0),
            ):
                module.apply(partial(self.init_weights, gain=gain))
        # The estimator is trained only by its own optimizer (EstimatorCallback); PPO's optimizer
        # must never hold its parameters, or PPO's steps would move it (weight decay, momentum).
        self.optimizer = self.optimizer_class(
            self.actor_critic_parameters(), lr=lr_schedule(1), **self.optimizer_kwargs
        )  # type: ignore[call-arg]
        self.estimator_optimizer: th.optim.Optimizer | None = None
        if self.estimator is not None:
            self.estimator_optimizer = th.optim.Adam(self.estimator.parameters(), lr=self.estimator_lr)

    def actor_critic_parameters(self) -> list[nn.Parameter]:
        """Every parameter except the estimator's (what the PPO optimizer holds)."""
        excluded = {id(p) for p in self.estimator.parameters()} if self.estimator is not None else set()
        return [p for p in self.parameters() if id(p) not in excluded]

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(
            use_dcbf=self.use_dcbf,
            use_estimator=self.use_estimator,
            avoid_collisions=self.avoid_collisions,
            freeze_steps=self.dcbf_config.freeze_steps,
            eta=self.dcbf_config.eta,
            gamma_threshold=self.dcbf_config.gamma_threshold,
            dcbf_barrier=self.dcbf_config.barrier,
            neglect_bound=self.dcbf_config.neglect_bound,
            neglect_scope=self.dcbf_config.neglect_scope,
            neglect_territory=list(self.dcbf_config.territory),
            laplacian=self._encoder_kwargs["laplacian"],
            gat_heads=self._encoder_kwargs["gat_heads"],
            hidden_dim=self._encoder_kwargs["hidden_dim"],
            gat_layers=self._encoder_kwargs["gat_layers"],
            gat_backend=self._encoder_kwargs["backend"],
            estimator_hidden=self.estimator_hidden,
            estimator_lr=self.estimator_lr,
            estimator_epochs=self.estimator_epochs,
            estimator_batch_size=self.estimator_batch_size,
            advice_prior=self.advice_prior,
        )
        return data

    # ------------------------------------------------------------- pieces
    def _preprocess(self, obs: PyTorchObs) -> dict[str, th.Tensor]:
        """SB3's preprocessing of the map, written out for its five keys (it runs on every env step).

        The result is what :func:`~stable_baselines3.common.preprocessing.preprocess_obs` gives,
        except that ``adjacency`` keeps its dtype (the env's int8 at collection time; the extractor
        reads it as ``!= 0`` and converts only the distinct graphs it needs as floats), and
        ``position_index`` ``(B,)`` long is added next to the one-hot ``position``.
        """
        assert isinstance(obs, dict)
        nodes = obs["nodes"].float()
        batch = nodes.shape[0]
        # A Discrete entry sampled from a rollout buffer is stored as (B, 1) float; a fresh one is (B,).
        position = obs["position"].reshape(batch).long()
        return {
            "nodes": nodes,
            "adjacency": obs["adjacency"],
            "position": nn.functional.one_hot(position, self.n_nodes).float(),
            "position_index": position,
            "dwell": obs["dwell"].float().reshape(batch, 1),
            "action_mask": obs["action_mask"].float(),
        }

    def uncertainty(self, pre: dict[str, th.Tensor]) -> th.Tensor:
        """``û`` ``(B, N)`` in units of ``u``: the estimator's (detached) or the map's last observed ``u``."""
        if self.estimator is None:
            return pre["nodes"][..., U]
        with th.no_grad():  # detached: neither PPO's loss nor its optimizer touch the estimator
            return self.estimator(pre["nodes"])

    def _masks(
        self, pre: dict[str, th.Tensor], u_hat: th.Tensor, given: th.Tensor | np.ndarray | None
    ) -> th.Tensor:
        """The DCBF mask (or the reachable set), intersected with a caller's mask if any."""
        mask, forced = self.filtered_masks(pre, u_hat, given)
        if forced is not None:
            self.count_forced(forced)
        return mask

    def filtered_masks(
        self, pre: dict[str, th.Tensor], u_hat: th.Tensor, given: th.Tensor | np.ndarray | None
    ) -> tuple[th.Tensor, th.Tensor | None]:
        """:meth:`_masks` without counting: the mask ``(B, N)`` bool, and where rule 8 forced it
        ``(B,)`` bool (``None`` when rule 8 is off)."""
        forced = None
        if self.use_dcbf:
            mask, forced = dcbf_filter_from_map(pre, u_hat, self.dcbf_config, self.u_max)
            if self.dcbf_config.neglect_bound is None:
                forced = None
        else:
            mask = pre["action_mask"] > 0.5
        if given is not None:
            given_t = th.as_tensor(given, device=mask.device).reshape(mask.shape).bool()
            both = mask & given_t
            mask = th.where(both.any(-1, keepdim=True), both, mask)
        return mask, forced

    def count_forced(self, forced: th.Tensor) -> None:
        """Add one batch of rule-8 decisions ``(B,)`` bool to :attr:`filter_counts`."""
        self.filter_counts["masks"] += int(forced.shape[0])
        self.filter_counts["forced"] = self.filter_counts["forced"] + forced.sum()

    def compute_masks(self, obs: PyTorchObs) -> th.Tensor:
        """The DCBF mask for raw (unpreprocessed) tensor observations, ``(B, N)`` bool."""
        pre = self._preprocess(obs)
        with th.no_grad():
            return self._masks(pre, self.uncertainty(pre), None)

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
        """Per-node logits ``(B, N)`` (see :meth:`_actor_logits`) and values ``(B, 1)``."""
        embeddings, own = self._node_inputs(pre, u_hat)
        logits = self._with_advice(self._actor_logits(embeddings, own), pre)
        return logits, self._value(embeddings, own)

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

    def _distribution(self, logits: th.Tensor, masks: th.Tensor) -> MaskableDistribution:
        distribution = self.action_dist.proba_distribution(action_logits=logits)
        distribution.apply_masking(masks)
        return distribution

    # ------------------------------------------------------- SB3 interface
    def forward_with_masks(
        self, obs: PyTorchObs, deterministic: bool = False
    ) -> tuple[th.Tensor, th.Tensor, th.Tensor, th.Tensor]:
        """Sample actions under the DCBF mask and return that mask too: :meth:`rollout_heads`, then
        :meth:`sample_masked`.

        :return: actions ``(B,)``, values ``(B, 1)``, log-probabilities ``(B,)`` and masks ``(B, N)`` bool.
        """
        logits, values, masks = self.rollout_heads(obs)
        actions, log_probs = self.sample_masked(logits, masks, deterministic)
        return actions, values, log_probs, masks

    def rollout_heads(self, obs: PyTorchObs) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
        """What a rollout step computes before its draw: logits ``(B, N)``, values ``(B, 1)`` and
        the DCBF masks ``(B, N)`` bool (counting rule 8's decisions)."""
        pre = self._preprocess(obs)
        u_hat = self.uncertainty(pre)
        masks = self._masks(pre, u_hat, None)
        logits, values = self._heads(pre, u_hat, masks)
        return logits, values, masks

    @staticmethod
    def sample_masked(
        logits: th.Tensor, masks: th.Tensor, deterministic: bool = False
    ) -> tuple[th.Tensor, th.Tensor]:
        """An action per map from ``softmax(logits)`` over the allowed nodes (the most likely one
        with ``deterministic``), drawn from torch's generator, and its log-probability.

        sb3-contrib's masked categorical, without building distribution objects: this runs once per
        env step with a batch of n_envs, where constructing and re-masking two Categoricals (each
        normalizing its logits) cost about a quarter of the step. Same masking constant, same
        normalization and the same multinomial draw as ``MaskableCategorical.sample()``.

        Shapes: logits ``(B, N)``, masks ``(B, N)`` bool -> actions ``(B,)``, log-probabilities ``(B,)``.
        """
        masked = th.where(masks, logits, _HUGE_NEG.to(logits.dtype))
        log_probs = th.log_softmax(masked, dim=-1)  # (B, N)
        if deterministic:
            actions = log_probs.argmax(-1)
        else:
            actions = th.multinomial(th.softmax(masked, dim=-1), 1, True).squeeze(-1)
        return actions, log_probs.gather(-1, actions.unsqueeze(-1)).squeeze(-1)

    def forward(  # type: ignore[override]
        self, obs: PyTorchObs, deterministic: bool = False, action_masks: np.ndarray | None = None
    ) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
        pre = self._preprocess(obs)
        u_hat = self.uncertainty(pre)
        masks = self._masks(pre, u_hat, action_masks)
        logits, values = self._heads(pre, u_hat, masks)
        distribution = self._distribution(logits, masks)
        actions = distribution.get_actions(deterministic=deterministic)
        return actions, values, distribution.log_prob(actions)

    def evaluate_actions(  # type: ignore[override]
        self, obs: PyTorchObs, actions: th.Tensor, action_masks: th.Tensor | None = None
    ) -> tuple[th.Tensor, th.Tensor, th.Tensor | None]:
        """Values, log-probabilities and entropies; ``action_masks`` (PPO's stored masks) are used as is."""
        pre = self._preprocess(obs)
        u_hat = self.uncertainty(pre)
        if action_masks is None:
            masks = self._masks(pre, u_hat, None)
        else:  # the stored mask, unchanged: recomputing it would corrupt PPO's ratio
            masks = th.as_tensor(action_masks, device=u_hat.device).reshape(u_hat.shape).bool()
        logits, values = self._heads(pre, u_hat, masks)
        distribution = self._distribution(logits, masks)
        return values, distribution.log_prob(actions), distribution.entropy()

    def get_distribution(
        self, obs: PyTorchObs, action_masks: np.ndarray | None = None
    ) -> MaskableDistribution:
        pre = self._preprocess(obs)
        u_hat = self.uncertainty(pre)
        masks = self._masks(pre, u_hat, action_masks)
        return self._distribution(self._logits(pre, u_hat, masks), masks)

    def predict_values(self, obs: PyTorchObs) -> th.Tensor:
        pre = self._preprocess(obs)
        return self._value(*self._node_inputs(pre, self.uncertainty(pre)))  # no actor, no mask

    @property
    def sampling_temperature(self) -> float:
        """Sampled (non-deterministic) predictions draw from ``softmax(logits / T)`` over the
        allowed nodes: ``T < 1`` sharpens towards the most likely action, ``T > 1`` flattens.
        Deployment only: training's rollouts and PPO's ratio use ``T = 1`` (``forward_with_masks``,
        ``evaluate_actions``), and it is not saved with the policy.

        :raises InputError: on setting anything but a positive finite number.
        """
        return self._sampling_temperature

    @sampling_temperature.setter
    def sampling_temperature(self, temperature: float) -> None:
        self._sampling_temperature = check_temperature(temperature)

    def set_training_mode(self, mode: bool) -> None:
        """SB3 calls this on every ``predict``; setting the mode on the whole module tree each time was
        13% of a learned team's evaluation step, so it is skipped when the policy and its direct
        children are already in that mode (nothing in the package toggles a deeper module alone)."""
        if self.training != mode or any(child.training != mode for child in self.children()):
            super().set_training_mode(mode)

    def draw(self, logits: th.Tensor, masks: th.Tensor) -> th.Tensor:
        """Actions drawn from ``logits`` over the allowed nodes at :attr:`sampling_temperature`,
        with get_distribution's arithmetic (acting, and the stacked pass's draws, which must equal
        it). Consumes torch's generator.

        Shapes:
            - logits: ``(B, N)``; masks: ``(B, N)`` bool
            - output: ``(B,)`` int64
        """
        if self._sampling_temperature != 1.0:
            logits = tempered_logits(logits, masks, self._sampling_temperature)
        return self._distribution(logits, masks).get_actions(deterministic=False)

    def _predict(  # type: ignore[override]
        self, observation: PyTorchObs, deterministic: bool = False, action_masks: np.ndarray | None = None
    ) -> th.Tensor:
        pre = self._preprocess(observation)
        u_hat = self.uncertainty(pre)
        masks = self._masks(pre, u_hat, action_masks)
        logits = self._logits(pre, u_hat, masks)
        if not deterministic:
            return self.draw(logits, masks)
        # The most likely action without building the distribution (three Categorical objects per
        # call in sb3-contrib, with argument checks): the same arithmetic, the same action.
        return masked_mode(logits, masks)
