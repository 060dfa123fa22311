"""Hyperparameter search samplers for rl-zoo's ``-optimize`` (``python -m sb3_pm.zoo optimize``).

rl-zoo samples a trial's hyperparameters with ``HYPERPARAMS_SAMPLER[algo]`` and lets them replace
the config's: PPO's sampler returns a whole ``policy_kwargs``, which would drop every setting of
the DCBF policy. Here ``maskable_ppo`` (and ``ppo_mask``) sample as PPO, and ``dcbf_ppo`` samples
PPO's hyperparameters plus the settings of the policy that matter, merged into the config's own
``policy_kwargs`` for the env being optimized:

* the GAT: ``hidden_dim`` (16, 32, 64), ``gat_layers`` (1 to 3), ``gat_heads`` (1, 2, 4);
* the estimator: ``estimator_lr`` (1e-4 to 1e-2, log-uniform), ``estimator_epochs`` (1 to 10);
* the DCBF filter: ``eta`` (0 to 0.5), ``freeze_steps`` (0 to 20), ``avoid_collisions``.

The samplers are bound to the config when the command line is read (:func:`register_samplers`),
since rl-zoo hands a sampler the trial alone.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import yaml

from sb3_pm.errors import UsageError


def config_policy_kwargs(args: Sequence[str]) -> dict[str, Any]:
    """The ``policy_kwargs`` of the ``-conf`` file's entry for ``--env`` (or its ``default``), as
    rl-zoo reads them; empty without a YAML ``-conf``."""
    from sb3_pm.zoo.rl_zoo import _option

    conf, env = _option(list(args), "-conf", "--conf-file"), _option(list(args), "--env")
    if conf is None or env is None or not conf[1].endswith((".yml", ".yaml")):
        return {}
    try:
        entries = yaml.safe_load(Path(conf[1]).read_text())
    except (OSError, yaml.YAMLError) as error:
        raise UsageError(f"-conf {conf[1]}: cannot read it ({error})") from error
    entry = entries.get(env[1], entries.get("default", {})) if isinstance(entries, dict) else {}
    kwargs = entry.get("policy_kwargs", {}) if isinstance(entry, dict) else {}
    if not isinstance(kwargs, dict):
        raise UsageError(f"-conf {conf[1]}: policy_kwargs of {env[1]!r} must be a mapping for a search")
    return dict(kwargs)


def dcbf_sampler(base_policy_kwargs: dict[str, Any]) -> Callable[..., dict[str, Any]]:
    """The ``dcbf_ppo`` sampler: PPO's hyperparameters, and the policy settings of the module
    docstring merged into ``base_policy_kwargs``."""
    from rl_zoo3.hyperparams_opt import sample_ppo_params

    def sample(trial: Any, n_actions: int, n_envs: int, additional_args: dict[str, Any]) -> dict[str, Any]:
        params = sample_ppo_params(trial, n_actions, n_envs, additional_args)
        policy_kwargs = {**base_policy_kwargs, **params.get("policy_kwargs", {})}
        policy_kwargs.update(
            hidden_dim=trial.suggest_categorical("hidden_dim", [16, 32, 64]),
            gat_layers=trial.suggest_int("gat_layers", 1, 3),
            gat_heads=trial.suggest_categorical("gat_heads", [1, 2, 4]),
            estimator_lr=trial.suggest_float("estimator_lr", 1e-4, 1e-2, log=True),
            estimator_epochs=trial.suggest_int("estimator_epochs", 1, 10),
            eta=trial.suggest_float("eta", 0.0, 0.5),
            freeze_steps=trial.suggest_int("freeze_steps", 0, 20),
            avoid_collisions=trial.suggest_categorical("avoid_collisions", [False, True]),
        )
        return {**params, "policy_kwargs": policy_kwargs}

    return sample


#: The policy settings :func:`dcbf_sampler` searches (they go into ``policy_kwargs``).
POLICY_SETTINGS = (
    "hidden_dim",
    "gat_layers",
    "gat_heads",
    "estimator_lr",
    "estimator_epochs",
    "eta",
    "freeze_steps",
    "avoid_collisions",
)


def dcbf_converter(base_policy_kwargs: dict[str, Any]) -> Callable[[dict[str, Any]], dict[str, Any]]:
    """Turns a finished trial's ``params`` (rl-zoo's ``--trial-id``) into hyperparameters, as the
    sampler built them: PPO's conversion, and the policy settings into ``policy_kwargs``."""
    from rl_zoo3.hyperparams_opt import convert_onpolicy_params

    def convert(params: dict[str, Any]) -> dict[str, Any]:
        ppo = {key: value for key, value in params.items() if key not in POLICY_SETTINGS}
        hyperparams = convert_onpolicy_params(ppo)
        settings = {key: value for key, value in params.items() if key in POLICY_SETTINGS}
        hyperparams["policy_kwargs"] = {
            **base_policy_kwargs,
            **hyperparams.get("policy_kwargs", {}),
            **settings,
        }
        return hyperparams  # type: ignore[no-any-return]

    return convert


def register_samplers(args: Sequence[str]) -> None:
    """Bind the samplers of our algorithms to the config of the command line ``args``."""
    from rl_zoo3.hyperparams_opt import HYPERPARAMS_CONVERTER, HYPERPARAMS_SAMPLER

    base = config_policy_kwargs(args)
    HYPERPARAMS_SAMPLER["dcbf_ppo"] = dcbf_sampler(base)
    HYPERPARAMS_CONVERTER["dcbf_ppo"] = dcbf_converter(base)
    for name in ("maskable_ppo", "ppo_mask"):
        HYPERPARAMS_SAMPLER[name] = HYPERPARAMS_SAMPLER["ppo"]
        HYPERPARAMS_CONVERTER[name] = HYPERPARAMS_CONVERTER["ppo"]


__all__ = ["POLICY_SETTINGS", "config_policy_kwargs", "dcbf_converter", "dcbf_sampler", "register_samplers"]
