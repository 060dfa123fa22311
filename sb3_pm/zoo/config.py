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
as rl-zoo does. Every key is checked against the algorithm's and the environment's signatures, so a
typo is an error that names the file, the entry and the key rather than a silently ignored value.
"""

from __future__ import annotations

import inspect
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from sb3_pm.errors import InputError
from sb3_pm.zoo.registry import (
    DEFAULT_POLICIES,
    RegistryError,
    default_algo,
    resolve_algo,
    resolve_policy_kwargs,
)
from sb3_pm.zoo.schedules import SCHEDULE_KEYS, check_spread, parse_schedule, staggered_learning_rates
from sb3_pm.zoo.shipped import resolve_config_path

DEFAULT_ENTRY = "default"
#: The tag of the last release with the research switches below (docs/RESEARCH_SNAPSHOT.md).
RESEARCH_TAG = "v0.1.0-research"
#: Research switches that measurement rejected and the package no longer has, as a config writes
#: them (an algorithm or ``policy_kwargs`` key, ``reward: <term>`` in ``env_kwargs``, or
#: ``laplacian: <value>``), with where they were set. :func:`check_removed` refuses them.
REMOVED_KEYS: dict[str, str] = {
    "extra_attention": "policy_kwargs",
    "derived_features": "policy_kwargs",
    "estimator_target": "policy_kwargs",
    "actor_nodes": "policy_kwargs",
    "gat_sparse_kernel": "policy_kwargs",
    "laplacian: eigen": "policy_kwargs",
    "ent_coef_final": "dcbf_ppo",
    "estimator_update_at": "dcbf_ppo",
    "reward: crowding": "env_kwargs",
    "reward: urgency": "env_kwargs",
    "reward: neglect": "env_kwargs",
}
#: Keys that belong to the team, not to one learner's algorithm.
TEAM_KEYS = (
    "n_timesteps",
    "n_envs",
    "n_agents",
    "algo",
    "env_kwargs",
    "agents",
    "env",
    "deploy_temperature",
    "deploy_filter",
    "learning_rate_spread",
)
#: Algorithm arguments the team sets itself (never from a config).
MANAGED_ARGS = {"self", "policy", "env", "seed", "tensorboard_log", "verbose", "device", "_init_setup_model"}
#: Keys allowed in a per-agent override: learner hyperparameters, but not the team's own keys
#: (n_steps is allowed so that the team can report a mismatch with a clear message).
AGENT_FORBIDDEN = set(TEAM_KEYS)


#: Provenance keys of a run folder's ``config.yml`` (not settings; skipped when it is read back).
RUN_RECORD_KEYS = ("entry", "source")


class ConfigError(InputError):
    """A malformed config; the message names the file, the entry and the key."""


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
    #: The DCBF neglect bound the trained team acts under (``{neglect_bound, neglect_scope}``), or
    #: ``None``: the filter it trained under (saved with the team; training never reads it).
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


def _algo_args(cls: type) -> dict[str, inspect.Parameter]:
    """Constructor arguments of ``cls`` a config may set (the team manages the rest).

    Walks the MRO while constructors forward ``**kwargs`` (``DCBFPPO(*args, update_device,
    **kwargs)`` passes everything else on to ``MaskablePPO``).
    """
    found: dict[str, inspect.Parameter] = {}
    for klass in cls.__mro__:
        if "__init__" not in vars(klass):
            continue
        parameters = inspect.signature(vars(klass)["__init__"]).parameters
        for name, p in parameters.items():
            if name not in MANAGED_ARGS and p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY):
                found.setdefault(name, p)
        if not any(p.kind is p.VAR_KEYWORD for p in parameters.values()):
            break
    return found


def _env_args() -> set[str]:
    from sb3_pm.envs.persistent_monitoring import PersistentMonitoringEnv

    parameters = inspect.signature(PersistentMonitoringEnv.__init__).parameters
    return {name for name in parameters if name not in ("self", "graph", "n_agents")}


#: Integer arguments of the algorithms that are counts or sizes, so at least 1.
POSITIVE_KEYS = frozenset({"n_steps", "batch_size", "n_epochs"})


def _as_int(value: Any, where: str, minimum: int = 1) -> int:
    """An integer from YAML, accepting ``5e4``-style numbers (PyYAML reads ``5e4`` as a string)."""
    if isinstance(value, bool):
        raise ConfigError(f"{where}: expected an integer, got {value!r}")
    if isinstance(value, str):
        try:
            value = float(value)
        except ValueError:
            raise ConfigError(f"{where}: expected an integer, got {value!r}") from None
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if not isinstance(value, int) or value < minimum:
        raise ConfigError(f"{where}: expected an integer >= {minimum}, got {value!r}")
    return value


def _check_hyperparam(key: str, value: Any, parameter: inspect.Parameter, where: str) -> Any:
    """Check ``value`` against the type of the argument's default; return it normalised."""
    default = parameter.default
    if key in SCHEDULE_KEYS:
        if value is None and default is None:  # clip_range_vf: None means "no clipping"
            return None
        try:
            parsed = parse_schedule(value, key)
        except ValueError as error:
            raise ConfigError(f"{where}: {error}") from None
        if isinstance(value, str) and value.strip().startswith("lin_"):
            return value.strip()  # kept as written; the team turns it into a schedule
        if isinstance(parsed, bool) or not isinstance(parsed, (int, float)):
            raise ConfigError(f"{where}: expected a number or lin_<number>, got {value!r}")
        return float(parsed)
    if key == "policy_kwargs":
        if value is None:
            return {}
        if not isinstance(value, dict):
            raise ConfigError(
                f"{where}: expected a mapping (not a string to eval), got {type(value).__name__}"
            )
        try:
            resolve_policy_kwargs(value)
        except (RegistryError, ImportError) as error:
            raise ConfigError(f"{where}: {error}") from None
        return dict(value)
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true/false, got {value!r}")
        return value
    if isinstance(default, int):
        # Sizes must be positive: n_steps: -5 used to reach numpy as "negative dimensions".
        return _as_int(value, where, minimum=1 if key in POSITIVE_KEYS else -(2**31))
    if isinstance(default, float):
        if isinstance(value, str):
            try:
                return float(value)
            except ValueError:
                pass
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}: expected a number, got {value!r}")
        return float(value)
    return value


def check_removed(settings: Mapping[str, Any], where: str) -> None:
    """Refuse a removed research switch (:data:`REMOVED_KEYS`) among ``settings``' keys, its
    ``policy_kwargs`` and its ``env_kwargs`` reward terms, naming it and the tag that has it.

    :param settings: a config entry or a learner's hyperparameters (``env_kwargs`` may be among them).
    :raises ConfigError: for the first removed switch found.
    """
    written = [str(key) for key in settings]
    policy_kwargs = settings.get("policy_kwargs")
    if isinstance(policy_kwargs, Mapping):
        written += [str(key) for key in policy_kwargs]
        written.append(f"laplacian: {policy_kwargs.get('laplacian')}")
    env_kwargs = settings.get("env_kwargs")
    reward = env_kwargs.get("reward") if isinstance(env_kwargs, Mapping) else None
    if isinstance(reward, Mapping):
        written += [f"reward: {term}" for term in reward]
    for name in written:
        if name in REMOVED_KEYS:
            raise ConfigError(
                f"{where}: {REMOVED_KEYS[name]} {name!r} was removed from sb3_pm; "
                f"the research snapshot tag {RESEARCH_TAG} has it"
            )


def _hyperparams(
    raw: Mapping[str, Any], allowed: Mapping[str, inspect.Parameter], where: str, extra: set[str]
) -> dict[str, Any]:
    checked: dict[str, Any] = {}
    for key, value in raw.items():
        if key in extra:
            continue
        if key not in allowed:
            raise ConfigError(
                f"{where}: unknown key {key!r} (not a team key, nor an argument of the algorithm)"
            )
        checked[key] = _check_hyperparam(key, value, allowed[key], f"{where}.{key}")
    return checked


#: Mapping-valued keys that command-line overrides merge into (key by key) instead of replacing.
MERGED_KEYS = ("policy_kwargs", "env_kwargs")


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


def load_config(path: str | Path, env: str, overrides: Mapping[str, Any] | None = None) -> TrainConfig:
    """Load the entry of ``path`` for graph ``env`` (a preset name or a GraphML path).

    :param overrides: entry keys to set on top of the file's (see :func:`apply_overrides`); they
        are validated like the file's own keys.
    :param path: a config file, or the name of a shipped one (``ippo``, ``ippo_paper``,
        ``ippo_improved``, ``ippo_transfer``).
    :raises FileNotFoundError: if the file does not exist.
    :raises ConfigError: for malformed YAML, unknown keys or wrong types (naming file and key).
    """
    source = str(resolve_config_path(path))
    data = read_yaml(source)
    entry = entry_for(data, env, source)
    raw = apply_overrides(data[entry], overrides or {})
    where = f"{source}: {entry}" + (" (with command-line overrides)" if overrides else "")
    check_removed(raw, where)

    algo = raw.get("algo") or default_algo()
    if not isinstance(algo, str):
        raise ConfigError(f"{where}.algo: expected a name, got {algo!r}")
    try:
        algo_class = resolve_algo(algo)
    except RegistryError as error:
        raise ConfigError(f"{where}.algo: {error}") from None
    allowed = _algo_args(algo_class)
    policy = raw.get("policy", DEFAULT_POLICIES.get(algo, "MultiInputPolicy"))
    if not isinstance(policy, str):
        raise ConfigError(f"{where}.policy: expected a policy name, got {policy!r}")

    env_kwargs = raw.get("env_kwargs") or {}
    if not isinstance(env_kwargs, dict):
        raise ConfigError(f"{where}.env_kwargs: expected a mapping, got {type(env_kwargs).__name__}")
    unknown_env = sorted(set(env_kwargs) - _env_args())
    if unknown_env:
        raise ConfigError(
            f"{where}.env_kwargs: unknown key {unknown_env[0]!r} (not an argument of the environment)"
        )

    train_env = raw.get("env")
    if train_env is not None and not isinstance(train_env, str):
        raise ConfigError(f"{where}.env: expected a graph or family name, got {train_env!r}")
    from sb3_pm.policies.sampling import check_deploy_temperature  # lazy: the module imports torch

    deploy_temperature = raw.get("deploy_temperature")
    try:
        deploy_temperature = check_deploy_temperature(deploy_temperature)
    except InputError as error:
        raise ConfigError(f"{where}.deploy_temperature: {error} (null acts by the argmax)") from None
    from sb3_pm.policies.dcbf import check_deploy_filter

    try:
        deploy_filter = check_deploy_filter(raw.get("deploy_filter"))
    except InputError as error:
        raise ConfigError(f"{where}.deploy_filter: {error} (null: the filter as trained)") from None
    hyperparams = _hyperparams(raw, allowed, where, set(TEAM_KEYS) | {"policy"})
    learning_rate_spread = check_learning_rate_spread(raw.get("learning_rate_spread", 1.0), where)
    n_agents = _as_int(raw.get("n_agents", 4), f"{where}.n_agents")
    agents_raw = raw.get("agents") or {}
    if not isinstance(agents_raw, dict):
        raise ConfigError(f"{where}.agents: expected a mapping agent_name -> overrides")
    agents: dict[str, dict[str, Any]] = {}
    names = {f"agent_{i}" for i in range(n_agents)}
    for agent, overrides in agents_raw.items():
        if agent not in names:
            raise ConfigError(
                f"{where}.agents: unknown agent {agent!r} (the team has agent_0 .. agent_{n_agents - 1})"
            )
        if not isinstance(overrides, dict):
            raise ConfigError(f"{where}.agents.{agent}: expected a mapping of hyperparameters")
        check_removed(overrides, f"{where}.agents.{agent}")
        forbidden = sorted(set(overrides) & AGENT_FORBIDDEN)
        if forbidden:
            raise ConfigError(
                f"{where}.agents.{agent}: {forbidden[0]!r} is set for the whole team, not per agent"
            )
        agents[agent] = _hyperparams(overrides, allowed, f"{where}.agents.{agent}", set())

    config = TrainConfig(
        source=source,
        entry=entry,
        n_timesteps=_as_int(raw.get("n_timesteps", 50_000), f"{where}.n_timesteps"),
        n_envs=_as_int(raw.get("n_envs", 1), f"{where}.n_envs"),
        n_agents=n_agents,
        algo=algo,
        policy=policy,
        hyperparams=hyperparams,
        env_kwargs=dict(env_kwargs),
        agents=agents,
        env=train_env,
        deploy_temperature=deploy_temperature,
        deploy_filter=deploy_filter,
        learning_rate_spread=learning_rate_spread,
    )
    config.per_agent()  # a spread without a learning rate fails here, not when a sweep's cell trains
    return config


def check_learning_rate_spread(value: Any, where: str = "config") -> float:
    """A ``learning_rate_spread`` as a float: a number >= 1 (1 switches the spread off).

    :raises ConfigError: for anything else, naming ``where``.
    """
    if isinstance(value, str):
        try:
            value = float(value)
        except ValueError:
            pass
    try:
        return check_spread(value)
    except InputError as error:
        raise ConfigError(f"{where}.{error}") from None


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
    "check_learning_rate_spread",
    "check_removed",
    "default_env",
    "entry_for",
    "load_config",
    "read_yaml",
]
