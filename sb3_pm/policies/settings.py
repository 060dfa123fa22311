"""The DCBF policy's settings, as a few config objects.

SB3 builds a policy from flat keyword arguments (a config's ``policy_kwargs``, a saved model's
data), so :class:`~sb3_pm.policies.policy.DCBFActorCriticPolicy` takes SB3's own arguments and
gathers every other one into a :class:`PolicySettings`: the graph encoder
(:class:`EncoderSettings`), the state estimator (:class:`EstimatorSettings`), the DCBF filter
(:class:`FilterSettings`) and the advice prior. Each key is documented, with its range, in
``docs/CONFIG.md`` (generated from :mod:`sb3_pm.zoo.schema`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field, fields
from typing import Any

import numpy as np
from gymnasium import spaces

from sb3_pm.envs.mental_map import FEATURES
from sb3_pm.errors import InputError
from sb3_pm.policies.dcbf import ADVICE_SWITCHES, DCBFConfig


@dataclass(frozen=True)
class EncoderSettings:
    """The GAT encoder: the Laplacian-rows encoding (``"rows"``) or none, heads per layer, the
    node embedding size ``h``, the number of layers and the attention kernel."""

    laplacian: str = "rows"
    gat_heads: int = 4
    hidden_dim: int = 32
    gat_layers: int = 2
    gat_backend: str = "auto"

    def extractor_kwargs(self) -> dict[str, Any]:
        """The keyword arguments of :class:`~sb3_pm.policies.extractor.GATFeaturesExtractor`."""
        return {
            "laplacian": self.laplacian,
            "gat_heads": self.gat_heads,
            "hidden_dim": self.hidden_dim,
            "gat_layers": self.gat_layers,
            "backend": self.gat_backend,
        }


@dataclass(frozen=True)
class EstimatorSettings:
    """The state estimator: whether it is built, its hidden sizes, and its own optimizer's learning
    rate, passes and minibatch size (pairs) per rollout."""

    use_estimator: bool = True
    estimator_hidden: tuple[int, ...] = (64, 64)
    estimator_lr: float = 1e-3
    estimator_epochs: int = 5
    estimator_batch_size: int = 256

    def __post_init__(self) -> None:
        object.__setattr__(self, "use_estimator", bool(self.use_estimator))
        object.__setattr__(self, "estimator_hidden", tuple(int(w) for w in self.estimator_hidden))
        object.__setattr__(self, "estimator_lr", float(self.estimator_lr))
        object.__setattr__(self, "estimator_epochs", int(self.estimator_epochs))
        object.__setattr__(self, "estimator_batch_size", int(self.estimator_batch_size))


@dataclass(frozen=True)
class FilterSettings:
    """The DCBF filter as a policy is built with it: on or off (off: the mask is the reachable
    set) and the fields of :class:`~sb3_pm.policies.dcbf.DCBFConfig` under their policy names."""

    use_dcbf: bool = True
    avoid_collisions: bool = False
    freeze_steps: int = 10
    eta: float = 0.1
    gamma_threshold: float = 0.0
    dcbf_barrier: bool = True
    neglect_bound: float | None = None
    neglect_scope: str = "known"
    neglect_territory: Sequence[int] = ()
    leave_cleared: bool = False
    pass_held: bool = False
    keep_moving: bool = False

    def __post_init__(self) -> None:
        if self.neglect_bound is not None and not self.use_dcbf:
            raise InputError("neglect_bound is rule 8 of the DCBF filter: it needs use_dcbf=True")

    def dcbf_config(self) -> DCBFConfig:
        """The filter's :class:`~sb3_pm.policies.dcbf.DCBFConfig` (which checks every field)."""
        return DCBFConfig(
            eta=self.eta,
            freeze_steps=int(self.freeze_steps),
            avoid_collisions=bool(self.avoid_collisions),
            gamma_threshold=float(self.gamma_threshold),
            barrier=bool(self.dcbf_barrier),
            neglect_bound=None if self.neglect_bound is None else float(self.neglect_bound),
            neglect_scope=str(self.neglect_scope),
            territory=tuple(int(node) for node in self.neglect_territory),
            leave_cleared=self.leave_cleared,
            pass_held=self.pass_held,
            keep_moving=self.keep_moving,
        )

    @classmethod
    def of(cls, use_dcbf: bool, config: DCBFConfig) -> FilterSettings:
        """The settings that build ``config`` (a policy's filter as it acts now)."""
        return cls(
            use_dcbf=use_dcbf,
            avoid_collisions=config.avoid_collisions,
            freeze_steps=config.freeze_steps,
            eta=config.eta,
            gamma_threshold=config.gamma_threshold,
            dcbf_barrier=config.barrier,
            neglect_bound=config.neglect_bound,
            neglect_scope=config.neglect_scope,
            neglect_territory=list(config.territory),
            leave_cleared=config.leave_cleared,
            pass_held=config.pass_held,
            keep_moving=config.keep_moving,
        )


@dataclass(frozen=True)
class PolicySettings:
    """Everything a DCBF policy is built with beyond SB3's own arguments.

    :ivar advice_prior: a fixed number added to the logit of the node the map's last column flags
        (the env's ``advice_input``: the territory rule's next move); ``0``: no prior.
    """

    encoder: EncoderSettings = field(default_factory=EncoderSettings)
    estimator: EstimatorSettings = field(default_factory=EstimatorSettings)
    filter: FilterSettings = field(default_factory=FilterSettings)
    advice_prior: float = 0.0

    @classmethod
    def from_kwargs(cls, kwargs: Mapping[str, Any]) -> PolicySettings:
        """The settings from flat keyword arguments (``policy_kwargs``), each key to its part.

        :raises InputError: a key no part takes, in one line that names it.
        """
        parts: dict[str, dict[str, Any]] = {"encoder": {}, "estimator": {}, "filter": {}}
        owner = {f.name: part for part, kind in _PARTS.items() for f in fields(kind)}
        advice_prior = 0.0
        for key, value in kwargs.items():
            if key == "advice_prior":
                advice_prior = value
            elif key in owner:
                parts[owner[key]][key] = value
            else:
                known = sorted([*owner, "advice_prior"])
                raise InputError(f"DCBFActorCriticPolicy has no setting {key!r}; its settings are {known}")
        return cls(
            encoder=EncoderSettings(**parts["encoder"]),
            estimator=EstimatorSettings(**parts["estimator"]),
            filter=FilterSettings(**parts["filter"]),
            advice_prior=advice_prior,
        )

    def to_kwargs(self) -> dict[str, Any]:
        """The flat keyword arguments that rebuild these settings (what SB3 saves)."""
        flat = {**asdict(self.encoder), **asdict(self.estimator), **asdict(self.filter)}
        flat["estimator_hidden"] = list(self.estimator.estimator_hidden)
        flat["neglect_territory"] = list(self.filter.neglect_territory)
        return {**flat, "advice_prior": self.advice_prior}


def check_advice_weight(
    key: str, value: Any, observation_space: spaces.Dict | None = None, use: str = "reads"
) -> float:
    """A weight on the env's advice (``advice_prior``, ``advice_imitation``) as a float: finite,
    ``>= 0``, and, given the ``observation_space``, positive only with a node column after the
    map's own (the env's ``advice_input``, which the team checks is on). ``use`` says in the error
    what ``key`` does with the advised node."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value) or value < 0:
        raise InputError(f"{key} must be a finite number >= 0, got {value!r}")
    if observation_space is not None and value > 0:
        columns = observation_space["nodes"].shape
        if columns is None or columns[-1] <= len(FEATURES):
            raise InputError(
                f"{key} {use} the node the env's advice_input flags: it needs advice_input: true"
            )
    return float(value)


def _filter_switch(switch: str) -> Callable[[Any], Any]:
    """Reads a learner's policy's filter switch ``switch`` (``False`` without a DCBF filter)."""
    return lambda learner: getattr(getattr(learner.policy, "dcbf_config", None), switch, False)


def check_advice_source(learners: Mapping[str, Any], env_kwargs: Mapping[str, Any]) -> None:
    """Refuse a policy's ``advice_prior`` or filter rule reading the advice (``pass_held``,
    ``keep_moving``), or a learner's
    ``advice_imitation``, unless the env appends the advice column: each reads the map's *last*
    column, which without ``advice_input`` is another feature (the territory's, with
    ``territory_input``). ``learners``: name -> SB3 learner (any algorithm; a key it does not have
    counts as unset)."""
    if env_kwargs.get("advice_input") is True:
        return
    readers: dict[str, Callable[[Any], Any]] = {
        "advice_prior": lambda learner: getattr(learner.policy, "advice_prior", 0.0),
        "advice_imitation": lambda learner: getattr(learner, "advice_imitation", 0.0),
        **{switch: _filter_switch(switch) for switch in ADVICE_SWITCHES},
    }
    for key, read in readers.items():
        with_key = [name for name, learner in learners.items() if read(learner)]
        if with_key:
            raise InputError(
                f"{key} (set for {with_key}) needs env_kwargs advice_input: true, whose column it reads"
            )


_PARTS: dict[str, type] = {
    "encoder": EncoderSettings,
    "estimator": EstimatorSettings,
    "filter": FilterSettings,
}

__all__ = [
    "EncoderSettings",
    "EstimatorSettings",
    "FilterSettings",
    "PolicySettings",
    "check_advice_weight",
    "check_advice_source",
]
