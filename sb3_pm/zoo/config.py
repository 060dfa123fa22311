"""rl-zoo style training configs: one YAML file, keyed by graph name, with a ``default:`` entry.

Example (``zoo/ippo.yml``)::

    default: &default
      n_timesteps: 20000          # per learner, as SB3 counts (a 4-agent team takes 4x that)
      n_envs: 2
      n_agents: 4
      algo: dcbf_ppo              # dcbf_ppo | maskable_ppo | ppo
      policy: DCBFPolicy          # optional: the algorithm's default policy
      n_steps: 250
      learning_rate: lin_3e-4     # linear decay to 0
      policy_kwargs:              # a real mapping; class names go through sb3_pm.zoo.registry
        activation_fn: ReLU
      env_kwargs: {max_cycles: 500}
      agents:                     # optional per-agent overrides
        agent_1: {learning_rate: 1.0e-4}
    paper-50:
      <<: *default
      n_timesteps: 50000

A graph looks up its own entry (the ``--env`` string, then the file stem of a GraphML path) and
falls back to ``default:``. Entries do not inherit from ``default:`` implicitly; use YAML anchors,
as rl-zoo does. Every key is checked, here and once, against :mod:`sb3_pm.zoo.schema` (the one list
of keys, with their types, ranges and meanings; docs/CONFIG.md's tables are generated from it), so a
typo or an out-of-range value is an error that names the file, the entry and the key rather than a
silently ignored value or a traceback mid-training.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from sb3_pm.errors import InputError
from sb3_pm.zoo.checks import ConfigError, check_batch, check_mapping, check_removed, check_value
from sb3_pm.zoo.registry import (
    DEFAULT_POLICIES,
    RegistryError,
    default_algo,
    resolve_algo,
    resolve_policy_kwargs,
)
from sb3_pm.zoo.schedules import staggered_learning_rates
from sb3_pm.zoo.schema import KEYS, REMOVED_KEYS, TEAM_KEYS, algorithm_keys, policy_keys
from sb3_pm.zoo.shipped import resolve_config_path

DEFAULT_ENTRY = "default"
#: Mapping-valued keys that command-line overrides merge into (key by key) instead of replacing.
MERGED_KEYS = ("policy_kwargs", "env_kwargs")


#: Provenance keys of a run folder's ``config.yml`` (not settings; skipped when it is read back).
RUN_RECORD_KEYS = ("entry", "source")


@dataclass
class TrainConfig:
    """One resolved config entry: everything :class:`~sb3_pm.agents.training.team.IndependentPPO` needs.

    Values are kept as written (``lin_3e-4`` stays a string) so the entry can be written back to
    a run folder's ``config.yml``; the team resolves schedules and class names itself.
    """

    source: str
    entry: str
    n_timesteps: int
    n_envs: int
    n_agents: int
    algo: str
    policy: str
    hyperparams: dict[str, Any] = field(default_factory=dict)
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    agents: dict[str, dict[str, Any]] = field(default_factory=dict)
    #: The graph or graph family this entry trains on when the command line names none
    #: (``sb3-pm train`` without ``--env``); ``None``: the default graph.
    env: str | None = None
    #: How the trained team acts by default: ``None`` by the argmax, a number by sampling at that
    #: temperature (saved with the team; training never reads it).
    deploy_temperature: float | None = None
    #: The DCBF rules the trained team acts under (``{neglect_bound, neglect_scope, leave_cleared,
    #: pass_held}``), or ``None``: the filter it trained under (saved with the team; training never reads it).
    deploy_filter: dict[str, Any] | None = None
    #: The fastest learner's learning rate over the slowest's (1: every learner the same); see
    #: :meth:`per_agent`.
    learning_rate_spread: float = 1.0

    def per_agent(self) -> dict[str, dict[str, Any]]:
        """Each learner's overrides: the ``agents`` block, plus, with a ``learning_rate_spread``
        other than 1, a ``learning_rate`` for every learner whose block does not set one.

        Computed here, from the final team size and learning rate, because an experiment or the
        command line may change either after the file is read.

        :raises ConfigError: for a spread without a numeric (or ``lin_``) ``learning_rate``.
        """
        per_agent = {agent: dict(values) for agent, values in self.agents.items()}
        if self.learning_rate_spread == 1.0:
            return per_agent
        if "learning_rate" not in self.hyperparams:
            raise ConfigError(
                f"{self.source}: {self.entry}.learning_rate_spread needs the entry's learning_rate"
            )
        try:
            rates = staggered_learning_rates(
                self.hyperparams["learning_rate"], self.learning_rate_spread, self.n_agents
            )
        except InputError as error:
            raise ConfigError(f"{self.source}: {self.entry}.{error}") from None
        for i, rate in enumerate(rates):
            per_agent.setdefault(f"agent_{i}", {}).setdefault("learning_rate", rate)
        return per_agent

    def team_kwargs(self) -> dict[str, Any]:
        """Keyword arguments of ``IndependentPPO`` (all but ``graph``, ``seed`` and logging)."""
        return {
            "n_agents": self.n_agents,
            "env_kwargs": dict(self.env_kwargs),
            "algo": self.algo,
            "policy": self.policy,
            "n_envs": self.n_envs,
            "hyperparams": dict(self.hyperparams),
            "per_agent": self.per_agent(),
            "deploy_temperature": self.deploy_temperature,
            "deploy_filter": None if self.deploy_filter is None else dict(self.deploy_filter),
        }

    def to_dict(self) -> dict[str, Any]:
        """The entry as plain YAML-able data (what a run folder's ``config.yml`` records)."""
        data: dict[str, Any] = {
            "n_timesteps": self.n_timesteps,
            "n_envs": self.n_envs,
            "n_agents": self.n_agents,
            "algo": self.algo,
            "policy": self.policy,
            **self.hyperparams,
            "env_kwargs": dict(self.env_kwargs),
        }
        if self.agents:
            data["agents"] = {agent: dict(values) for agent, values in self.agents.items()}
        if self.env is not None:
            data["env"] = self.env
        if self.deploy_temperature is not None:
            data["deploy_temperature"] = self.deploy_temperature
        if self.deploy_filter is not None:
            data["deploy_filter"] = dict(self.deploy_filter)
        if self.learning_rate_spread != 1.0:
            data["learning_rate_spread"] = self.learning_rate_spread
        return data


def read_yaml(path: str | Path) -> dict[str, Any]:
    """Parse a config file into a mapping of entries.

    :param path: a path, or the name of a shipped config (see :mod:`sb3_pm.zoo.shipped`).
    :raises FileNotFoundError: if it does not exist.
    :raises ConfigError: for malformed YAML or a file that is not a mapping of mappings.
    """
    file = resolve_config_path(path)
    try:
        data = yaml.safe_load(file.read_text())
    except yaml.YAMLError as error:
        raise ConfigError(f"{file}: malformed YAML: {error}".replace("\n", " ")) from error
    if not isinstance(data, dict):
        raise ConfigError(
            f"{file}: expected a mapping of entries (graph name -> settings), got {type(data).__name__}"
        )
    if isinstance(data.get("algo"), str):
        # A run folder's config.yml: one resolved entry, as ``sb3-pm train`` recorded it (with its
        # provenance, ``entry`` and ``source``, and the graph it trained on as ``env``). It is its
        # own default entry, so ``--config RUN/config.yml`` retrains what that run trained even
        # after the shipped config it came from has changed.
        data = {DEFAULT_ENTRY: {key: value for key, value in data.items() if key not in RUN_RECORD_KEYS}}
    for entry, value in data.items():
        if not isinstance(value, dict):
            raise ConfigError(f"{file}: entry {entry!r} must be a mapping, got {type(value).__name__}")
    return data


def entry_for(data: Mapping[str, Any], env: str, source: str = "config") -> str:
    """The entry used for ``env``: its own (by string, then file stem), else ``default``."""
    candidates = [str(env)]
    if str(env).lower().endswith((".graphml", ".xml")):
        candidates.append(Path(env).stem)
    for candidate in candidates:
        if candidate in data:
            return candidate
    if DEFAULT_ENTRY in data:
        return DEFAULT_ENTRY
    raise ConfigError(f"{source}: no entry for {env!r} and no {DEFAULT_ENTRY!r} entry")


def apply_overrides(raw: Mapping[str, Any], overrides: Mapping[str, Any]) -> dict[str, Any]:
    """``raw`` with ``overrides`` on top: ``policy_kwargs`` and ``env_kwargs`` merge key by key (so
    ``policy_kwargs: {avoid_collisions: true}`` keeps the file's other policy kwargs), anything else
    is replaced, as rl-zoo's ``--hyperparams`` does."""
    merged = dict(raw)
    for key, value in overrides.items():
        if key in MERGED_KEYS and isinstance(value, Mapping) and isinstance(merged.get(key), Mapping):
            merged[key] = {**merged[key], **value}
        else:
            merged[key] = value
    return merged


def load_config(
    path: str | Path,
    env: str,
    overrides: Mapping[str, Any] | None = None,
    origin: str = "command-line overrides",
) -> TrainConfig:
    """Load the entry of ``path`` for graph ``env`` (a preset name or a GraphML path), every key
    checked against :mod:`sb3_pm.zoo.schema`.

    :param path: a config file, or the name of a shipped one (``ippo``, ``ippo_split``,
        ``ippo_paper``, ``ippo_improved``, ``ippo_transfer``, ``ippo_transfer_prior4``,
        ``ippo_transfer_split``).
    :param overrides: entry keys to set on top of the file's (see :func:`apply_overrides`); they
        are validated like the file's own keys.
    :param origin: where the overrides come from, for error messages.
    :raises FileNotFoundError: if the file does not exist.
    :raises ConfigError: for malformed YAML, unknown keys, wrong types or values out of range (one
        line naming the file, the entry and the key).
    """
    source = str(resolve_config_path(path))
    data = read_yaml(source)
    entry = entry_for(data, env, source)
    raw = apply_overrides(data[entry], overrides or {})
    where = f"{source}: {entry}" + (f" (with {origin})" if overrides else "")
    check_removed(raw, where)

    algo = raw.get("algo") or default_algo()
    if not isinstance(algo, str):
        raise ConfigError(f"{where}.algo: expected a name, got {algo!r}")
    try:
        resolve_algo(algo)
    except RegistryError as error:
        raise ConfigError(f"{where}.algo: {error}") from None
    policy = raw.get("policy", DEFAULT_POLICIES.get(algo, "MultiInputPolicy"))
    if not isinstance(policy, str):
        raise ConfigError(f"{where}.policy: expected a policy name, got {policy!r}")
    team_keys = KEYS["team"]
    team = {
        key: check_value(team_keys[key], raw.get(key, team_keys[key].default), f"{where}.{key}", loose=True)
        for key in TEAM_KEYS
        if key not in ("algo", "policy")
    }
    env_kwargs = check_mapping(
        team["env_kwargs"] or {}, KEYS["env"], f"{where}.env_kwargs", "an argument of the environment"
    )
    learner = {key: value for key, value in raw.items() if key not in TEAM_KEYS}
    hyperparams = _learner_settings(learner, algo, policy, where)
    check_batch(hyperparams, team["n_envs"], where)
    n_agents = team["n_agents"]
    agents: dict[str, dict[str, Any]] = {}
    names = {f"agent_{i}" for i in range(n_agents)}
    for agent, settings in (team["agents"] or {}).items():
        if agent not in names:
            raise ConfigError(
                f"{where}.agents: unknown agent {agent!r} (the team has agent_0 .. agent_{n_agents - 1})"
            )
        if not isinstance(settings, dict):
            raise ConfigError(f"{where}.agents.{agent}: expected a mapping of hyperparameters")
        check_removed(settings, f"{where}.agents.{agent}")
        forbidden = sorted(set(settings) & set(TEAM_KEYS))
        if forbidden:
            raise ConfigError(
                f"{where}.agents.{agent}: {forbidden[0]!r} is set for the whole team, not per agent"
            )
        agents[agent] = _learner_settings(settings, algo, policy, f"{where}.agents.{agent}")
        check_batch({**hyperparams, **agents[agent]}, team["n_envs"], f"{where}.agents.{agent}")

    config = TrainConfig(
        source=source,
        entry=entry,
        n_timesteps=team["n_timesteps"],
        n_envs=team["n_envs"],
        n_agents=n_agents,
        algo=algo,
        policy=policy,
        hyperparams=hyperparams,
        env_kwargs=env_kwargs,
        agents=agents,
        env=team["env"],
        deploy_temperature=team["deploy_temperature"],
        deploy_filter=team["deploy_filter"],
        learning_rate_spread=team["learning_rate_spread"],
    )
    config.per_agent()  # a spread without a learning rate fails here, not when a sweep's cell trains
    return config


def _learner_settings(settings: Mapping[str, Any], algo: str, policy: str, where: str) -> dict[str, Any]:
    """A learner's algorithm keys (an entry's, or one agent's overrides), checked and normalised;
    ``policy_kwargs`` checked against the keys ``policy`` takes, class names resolved."""
    what = f"a team key, nor an argument of {algo}"
    checked = check_mapping(settings, algorithm_keys(algo), where, what, loose=True)
    if "policy_kwargs" in checked:
        policy_kwargs = checked["policy_kwargs"] or {}
        keys = policy_keys(policy)
        check_mapping(policy_kwargs, keys, f"{where}.policy_kwargs", f"an argument of {policy}")
        try:
            resolve_policy_kwargs(policy_kwargs)
        except (RegistryError, ImportError) as error:
            raise ConfigError(f"{where}.policy_kwargs: {error}") from None
        checked["policy_kwargs"] = dict(policy_kwargs)
    return checked


def default_env(path: str | Path) -> str | None:
    """The ``env`` of a config's ``default`` entry: what ``sb3-pm train`` trains on without ``--env``.

    :raises ConfigError: for malformed YAML or an ``env`` that is not a string.
    """
    source = str(resolve_config_path(path))
    entry = read_yaml(source).get(DEFAULT_ENTRY) or {}
    env = entry.get("env")
    if env is not None and not isinstance(env, str):
        raise ConfigError(f"{source}: {DEFAULT_ENTRY}.env: expected a graph or family name, got {env!r}")
    return env


__all__ = [
    "DEFAULT_ENTRY",
    "REMOVED_KEYS",
    "ConfigError",
    "TrainConfig",
    "apply_overrides",
    "check_removed",
    "default_env",
    "entry_for",
    "load_config",
    "read_yaml",
]
