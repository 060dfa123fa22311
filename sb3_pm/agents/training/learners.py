"""Learner settings: the algorithm and policy a team's learners use, their hyperparameters, seeds."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from sb3_pm.errors import InputError
from sb3_pm.zoo.config import check_removed
from sb3_pm.zoo.registry import (
    DEFAULT_POLICIES,
    algo_name,
    default_algo,
    resolve_algo,
    resolve_policy_kwargs,
    uses_masks,
)
from sb3_pm.zoo.schedules import SCHEDULE_KEYS, parse_schedule

#: Keys the team sets itself; a hyperparameter dict must not hold them.
RESERVED_KEYS = (
    "env",
    "policy",
    "seed",
    "tensorboard_log",
    "verbose",
    "device",
    "update_device",  # this machine's, as device is: team.update_device, never saved
    "_init_setup_model",
)


def agent_seed(seed: int, index: int) -> int:
    """A distinct, reproducible seed for agent ``index`` of a team seeded with ``seed``.

    Derived through NumPy's ``SeedSequence`` so that agent 1 of seed 0 differs from agent 0 of
    seed 1 (``seed + index`` would make them equal).
    """
    return int(np.random.SeedSequence([int(seed), int(index)]).generate_state(1)[0])


def learn_seed(seed: int, num_timesteps: int) -> int:
    """The seed of the process-wide generators at the start of a ``learn()`` call.

    Distinct from every :func:`agent_seed` (its entropy has three words, theirs two).
    """
    return int(np.random.SeedSequence([int(seed), int(num_timesteps), 1]).generate_state(1)[0])


def check_same(values: Mapping[str, Any], key: str) -> None:
    if len(set(values.values())) > 1:
        listed = ", ".join(f"{agent}={value}" for agent, value in values.items())
        raise InputError(
            f"every learner of a team must use the same {key} (they are stepped together); got {listed}"
        )


def resolve_learner(
    algo: str | type | None, policy: str | type | None, env_kwargs: Mapping[str, Any] | None
) -> tuple[Any, str, str | type, dict[str, Any]]:
    """The algorithm class and its registry name, the policy (the algorithm's default when None),
    and the env kwargs a learner of that algorithm needs.

    ``algo=None`` picks ``dcbf_ppo`` when importable. An algorithm without action masks may pick
    any node, and the env's default ``illegal_action="raise"`` would end training: such learners
    get ``illegal_action="stay"`` unless the caller set it.
    """
    algo = algo if algo is not None else default_algo()
    algo_class = resolve_algo(algo) if isinstance(algo, str) else algo
    name = algo if isinstance(algo, str) else algo_name(algo)
    policy = policy if policy is not None else DEFAULT_POLICIES.get(name, "MultiInputPolicy")
    kwargs = dict(env_kwargs or {})
    check_removed({"env_kwargs": kwargs}, "env_kwargs")
    if not uses_masks(algo_class):
        kwargs.setdefault("illegal_action", "stay")
    return algo_class, name, policy, kwargs


def resolve_hyperparams(hyperparams: Mapping[str, Any]) -> dict[str, Any]:
    """Config values -> algorithm keyword arguments: ``lin_`` schedules become SB3 schedules and
    ``policy_kwargs`` class names become classes."""
    resolved = dict(hyperparams)
    for key in SCHEDULE_KEYS:
        if key in resolved:
            resolved[key] = parse_schedule(resolved[key], key)
    if "policy_kwargs" in resolved:
        resolved["policy_kwargs"] = resolve_policy_kwargs(resolved["policy_kwargs"])
    return resolved


def learner_kwargs(
    hyperparams: Mapping[str, Any], overrides: Mapping[str, Any], agent: str, n_envs: int
) -> dict[str, Any]:
    """The algorithm's keyword arguments for one learner: the team's shared hyperparameters, then
    the agent's overrides, with ``lin_`` schedules and ``policy_kwargs`` class names resolved.

    :raises InputError: for a key the team sets itself, a removed research switch, or an
        ``n_envs`` other than the team's.
    """
    merged = {**hyperparams, **overrides}
    check_removed(merged, f"hyperparameters of {agent}")
    for key in RESERVED_KEYS:
        if key in merged and key != "policy":
            raise InputError(
                f"hyperparameter {key!r} ({agent}) is set by the team; pass it to IndependentPPO"
            )
    if "n_envs" in merged and int(merged.pop("n_envs")) != n_envs:
        raise InputError(
            f"every learner of a team must use the same n_envs; {agent} asks for a different one "
            f"than the team's {n_envs}"
        )
    return resolve_hyperparams(merged)


__all__ = [
    "RESERVED_KEYS",
    "agent_seed",
    "check_same",
    "learn_seed",
    "learner_kwargs",
    "resolve_hyperparams",
    "resolve_learner",
]
