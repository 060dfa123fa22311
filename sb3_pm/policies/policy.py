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

from dataclasses import replace
from functools import partial
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from sb3_contrib.common.maskable.distributions import MaskableDistribution
from sb3_contrib.common.maskable.policies import MaskableActorCriticPolicy
from stable_baselines3.common.type_aliases import PyTorchObs, Schedule
from torch import nn

from sb3_pm.envs.mental_map import U
from sb3_pm.errors import InputError
from sb3_pm.policies.dcbf import ADVICE_SWITCHES, check_bound_below_cap, dcbf_filter_from_map
from sb3_pm.policies.edges import DENSE_MAP_KEYS, EDGE_MAP_KEYS, is_edge_layout
from sb3_pm.policies.estimator import StateEstimator
from sb3_pm.policies.extractor import GATFeaturesExtractor
from sb3_pm.policies.heads import ActorCriticHeads, masked_mode
from sb3_pm.policies.sampling import check_temperature, tempered_logits
from sb3_pm.policies.settings import FilterSettings, PolicySettings, check_advice_weight
from sb3_pm.policies.visit_deadline import VISIT_AGE, VISIT_TARGETS

#: The keys of a map observation in the env's dense layout (the edges layout's: ``EDGE_MAP_KEYS``).
MAP_KEYS = DENSE_MAP_KEYS
#: Logit given to masked-out actions, sb3-contrib's ``MaskableCategorical`` value.
_HUGE_NEG = th.tensor(-1e8)


def _mlp(in_dim: int, hidden: list[int], activation: type[nn.Module]) -> tuple[nn.Sequential, int]:
    layers: list[nn.Module] = []
    for width in hidden:
        layers += [nn.Linear(in_dim, width), activation()]
        in_dim = width
    return nn.Sequential(*layers), in_dim


class DCBFActorCriticPolicy(ActorCriticHeads, MaskableActorCriticPolicy):
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
    :param settings: everything else, as flat keyword arguments (a config's ``policy_kwargs``),
        gathered into a :class:`~sb3_pm.policies.settings.PolicySettings`: the graph encoder's
        (``laplacian``, ``gat_heads``, ``hidden_dim``, ``gat_layers``, ``gat_backend``), the state
        estimator's (``use_estimator``, ``estimator_hidden``, ``estimator_lr``,
        ``estimator_epochs``, ``estimator_batch_size``), the DCBF filter's (``use_dcbf``,
        ``avoid_collisions``, ``freeze_steps``, ``eta``, ``gamma_threshold``, ``dcbf_barrier``,
        ``neglect_bound``, ``neglect_scope``, ``neglect_territory``, ``leave_cleared``, ``pass_held``,
        ``keep_moving``;
        :mod:`sb3_pm.policies.dcbf`)
        and ``advice_prior`` (a fixed number added to the logit of the territory rule's next move,
        the env's ``advice_input``). ``docs/CONFIG.md`` gives each its default and range.
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
        **settings: Any,
    ) -> None:
        if not isinstance(observation_space, spaces.Dict) or any(
            k not in observation_space.spaces
            for k in (EDGE_MAP_KEYS if is_edge_layout(observation_space.spaces) else MAP_KEYS)
        ):
            raise InputError(
                f"DCBFActorCriticPolicy needs the mental-map Dict observation with keys {MAP_KEYS} "
                f"(or {EDGE_MAP_KEYS} in the edges layout)"
            )
        if not isinstance(action_space, spaces.Discrete):
            raise InputError(f"DCBFActorCriticPolicy needs a Discrete action space, got {action_space}")
        if not share_features_extractor:
            raise InputError("DCBFActorCriticPolicy shares its graph encoder between actor and critic")
        # Plain attributes are set before nn.Module.__init__ (allowed for non-tensors) because the
        # parent constructor calls our _build, which reads them.
        self.settings = PolicySettings.from_kwargs(settings)
        self.use_dcbf = self.settings.filter.use_dcbf
        self.use_estimator = self.settings.estimator.use_estimator
        self.avoid_collisions = self.settings.filter.avoid_collisions
        self.advice_prior = check_advice_weight(
            "advice_prior", self.settings.advice_prior, observation_space, use="adds to"
        )
        self.dcbf_config = self.settings.filter.dcbf_config()
        for switch in ADVICE_SWITCHES:  # rules 10 and 11 read the advice column; the check says where
            if getattr(self.dcbf_config, switch):
                check_advice_weight(switch, 1.0, observation_space, use="reads")
        #: The filter as built from the constructor: a deployed team acts under it with its own
        #: settings on top (``DeploymentRule.set_filter``), and ``reset_filter`` restores it.
        self.trained_dcbf_config = self.dcbf_config
        #: Masks the filter computed with rule 8 (the neglect bound) on, and how many it forced: a
        #: diagnostic read by ``DeploymentRule.filter_activity()``, never saved. ``forced`` is summed
        #: as a tensor, so counting costs no device synchronisation per forward pass.
        self.filter_counts: dict[str, Any] = {"masks": 0, "forced": 0}
        #: Rule 12's inputs for the maps of the next call, ``(visit set, steps since the agent's own
        #: visit)``, each ``(B, N)``: set by the deployed team before each step, never saved.
        self.visit_inputs: tuple[th.Tensor, th.Tensor] | None = None
        self._sampling_temperature = 1.0
        estimator = self.settings.estimator
        self.estimator_hidden = list(estimator.estimator_hidden)
        self.estimator_lr, self.estimator_epochs = estimator.estimator_lr, estimator.estimator_epochs
        self.estimator_batch_size = estimator.estimator_batch_size
        self._encoder_kwargs = self.settings.encoder.extractor_kwargs()
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
        """SB3's constructor arguments, with the settings flat and the filter as it acts now."""
        data = super()._get_constructor_parameters()
        acting = FilterSettings.of(self.use_dcbf, self.dcbf_config)
        data.update(replace(self.settings, filter=acting, advice_prior=self.advice_prior).to_kwargs())
        return data

    # ------------------------------------------------------------- pieces
    def _preprocess(self, obs: PyTorchObs) -> dict[str, th.Tensor]:
        """SB3's preprocessing of the map, written out for its five keys (it runs on every env step).

        The result is what :func:`~stable_baselines3.common.preprocessing.preprocess_obs` gives,
        except that ``adjacency`` (or, in the edges layout, ``edge_index`` and ``edge_mask``) keeps
        its dtype (the env's int8 at collection time; the extractor
        reads it as ``!= 0`` and converts only the distinct graphs it needs as floats), and
        ``position_index`` ``(B,)`` long is added next to the one-hot ``position``.
        """
        assert isinstance(obs, dict)
        nodes = obs["nodes"].float()
        batch = nodes.shape[0]
        # A Discrete entry sampled from a rollout buffer is stored as (B, 1) float; a fresh one is (B,).
        position = obs["position"].reshape(batch).long()
        graph = (
            {"edge_index": obs["edge_index"], "edge_mask": obs["edge_mask"]}
            if "adjacency" not in obs
            else {"adjacency": obs["adjacency"]}
        )
        return {
            "nodes": nodes,
            **graph,
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
            if self.visit_inputs is not None and VISIT_TARGETS not in pre:
                pre = {**pre, VISIT_TARGETS: self.visit_inputs[0], VISIT_AGE: self.visit_inputs[1]}
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
