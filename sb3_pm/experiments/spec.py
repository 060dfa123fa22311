"""Experiment definitions: the YAML files under ``zoo/experiments/``.

An experiment is a grid of *variants* (algorithms or ablations) x graphs x training seeds, each
evaluated for a number of episodes. One file describes it::

    name: comparison
    graphs: [paper-50, paper-100, paper-200]   # preset names or .graphml paths
    seeds: [0, 1, 2]                           # training seeds (evaluation seeds derive from them)
    episodes: 10                               # evaluation episodes per cell
    max_cycles: 500
    n_agents: 4
    config: ../ippo.yml                        # the rl-zoo style training config (relative to this file)
    timesteps: 50000                           # per learner; null = the config's n_timesteps
    hyperparams: {}                            # merged into every learned variant's config entry
    eval_env_kwargs: {}                        # env arguments of every cell's evaluation, never of
                                               # training (deployment conditions: failures: {agent_1: 250})
    quick: {seeds: [0], episodes: 2, max_cycles: 50, timesteps: 512}   # --quick overrides
    variants:
      proposed: {kind: independent}                     # IndependentPPO with the base config
      no_dcbf: {kind: independent, policy_kwargs: {use_dcbf: false}}
      centralized: {kind: centralized}                  # one shared map + network, same model code
      grazing: {kind: baseline, policy: grazing}

Variant keys: ``kind`` (``independent``, ``centralized`` or ``baseline``), ``policy`` (baselines: a
baseline name), ``policy_kwargs`` / ``hyperparams`` / ``env_kwargs`` (learned variants: overrides
merged over the base config; a baseline's ``env_kwargs`` set its evaluation env over the
experiment's, e.g. the same ``target_knowledge`` as a learned variant), ``train`` (learned variants,
default true; ``false`` builds the team and evaluates its *initial* policy without training it: the
control that tells how much of a learned row comes from training rather than from the DCBF filter
around an untrained actor), ``config`` (learned variants: another team config to start from,
relative to this file, instead of the experiment's; the variant's overrides then merge over that
one), ``label`` (the name in tables; defaults to the key), ``hyperparams: {deploy_temperature:
...}`` (learned variants: how the trained team acts in the cells' evaluations, over the config's;
``null`` by the argmax, a number by sampling at it), ``train_env`` (independent variants: train
once per seed on this graph or graph family, e.g. ``family:er``, and evaluate that one team
zero-shot on every graph of the experiment, instead of training on each graph), ``timesteps``
(learned variants: this variant's budget per learner, instead of the experiment's), ``agents``
(independent variants: per-agent overrides, ``{agent_1: {learning_rate: 0.0007}}``, set as the
config file's own ``agents`` key would be, replacing it, and validated the same way),
``train_agents`` (independent variants with ``train_env``: the team size it trains with, instead
of the experiment's ``n_agents``; the cells deploy that team with ``n_agents``, agent_i acting
with learner agent_(i mod train_agents), e.g. a 4-agent team in the 16-agent regime).

Both lists of keys, with their types and ranges, are sections of :mod:`sb3_pm.zoo.schema`
(``experiment`` and ``variant``), as docs/CONFIG.md shows them.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import yaml

from sb3_pm.errors import InputError
from sb3_pm.zoo.schema import KEYS

VARIANT_KINDS = KEYS["variant"]["kind"].choices
#: Env arguments the experiment itself sets; an evaluation's or a baseline's env_kwargs may not.
_EXPERIMENT_ENV_KEYS = frozenset({"graph", "n_agents", "max_cycles"})
#: The experiment's scalar settings, checked as the schema says (no ``50.0`` for ``max_cycles``).
_SCALARS = ("episodes", "max_cycles", "n_agents", "timesteps")


class ExperimentError(InputError):
    """A malformed experiment file (the message names the file and the key)."""


@dataclass(frozen=True)
class Variant:
    """One row of the results table."""

    key: str
    kind: str
    label: str
    policy: str | None = None
    policy_kwargs: dict[str, Any] = field(default_factory=dict)
    hyperparams: dict[str, Any] = field(default_factory=dict)
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    train: bool = True
    config: str | None = None
    #: Train once per seed on this graph or family and evaluate that team on every graph.
    train_env: str | None = None
    #: This variant's budget per learner (``None``: the experiment's).
    timesteps: int | None = None
    #: Per-agent overrides (``agent_i -> hyperparameters``), as a config entry's ``agents`` key.
    agents: dict[str, dict[str, Any]] = field(default_factory=dict)
    #: The team size a ``train_env`` variant trains with (``None``: the experiment's ``n_agents``).
    train_agents: int | None = None

    @property
    def learned(self) -> bool:
        return self.kind != "baseline"


@dataclass(frozen=True)
class Experiment:
    """A parsed experiment file; see the module docstring."""

    name: str
    graphs: tuple[str, ...]
    seeds: tuple[int, ...]
    episodes: int
    max_cycles: int
    n_agents: int
    config: Path | None
    timesteps: int | None
    variants: tuple[Variant, ...]
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    #: Environment arguments of the evaluation only (never of training), for every cell:
    #: deployment conditions such as agent failures (``failures: {agent_1: 250}``).
    eval_env_kwargs: dict[str, Any] = field(default_factory=dict)
    hyperparams: dict[str, Any] = field(default_factory=dict)
    quick_overrides: dict[str, Any] = field(default_factory=dict)
    source: Path | None = None

    def quick(self) -> Experiment:
        """The ``--quick`` version: smaller budgets for smoke tests (its numbers are not results)."""
        overrides = _coerce_top(self.quick_overrides, self.source, base=self.source)
        variants = self.variants
        if "hyperparams" in overrides:  # merged, so the file's pins (learning_rate_spread) hold
            budget = overrides["hyperparams"]
            overrides["hyperparams"] = {**self.hyperparams, **budget}
            # The smoke test's own keys (rollout size, epochs) win over a variant's too, as its
            # timesteps do; the variant's other keys (its pins) hold.
            variants = tuple(
                replace(v, hyperparams={k: x for k, x in v.hyperparams.items() if k not in budget})
                for v in variants
            )
        if "timesteps" in overrides:  # the smoke-test budget wins over every variant's own
            variants = tuple(replace(v, timesteps=None) for v in variants)
        overrides["variants"] = variants
        return replace(self, **overrides)

    def with_graphs(self, graphs: list[str]) -> Experiment:
        return replace(self, graphs=tuple(graphs))


def _fail(source: Path | None, message: str) -> ExperimentError:
    return ExperimentError(f"{source or '<experiment>'}: {message}")


def _coerce_top(raw: dict[str, Any], source: Path | None, base: Path | None) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in raw.items():
        if key not in set(KEYS["experiment"]) - {"variants", "quick", "name", "description"}:
            raise _fail(source, f"unknown or unsupported key {key!r} in quick overrides")
        _check_scalar(key, value, source, "quick.")
        if key in ("graphs",):
            out[key] = tuple(str(g) for g in value)
        elif key == "seeds":
            out[key] = tuple(int(s) for s in value)
        elif key == "config":
            out[key] = (base.parent / str(value)) if base else Path(str(value))
        else:
            out[key] = value
    return out


def _check_scalar(key: str, value: Any, source: Path | None, where: str = "") -> None:
    """Refuse a scalar setting of the wrong type or out of range (:data:`_SCALARS`), or a seed
    that is not an integer >= 0, naming it."""
    from sb3_pm.zoo.checks import check_value

    try:
        if key in _SCALARS:
            check_value(KEYS["experiment"][key], value, f"{where}{key}")
    except InputError as error:
        raise _fail(source, str(error)) from None
    if key == "seeds" and isinstance(value, list):
        bad = [s for s in value if isinstance(s, bool) or not isinstance(s, int) or s < 0]
        if bad:
            raise _fail(source, f"{where}seeds: expected integers >= 0, got {bad[0]!r}")


def _check_settings(settings: dict[str, Any], source: Path, where: str) -> None:
    """Check the config keys of an experiment's or a variant's ``settings`` against the schema:
    ``hyperparams`` (team and algorithm keys, :func:`sb3_pm.zoo.checks.check_settings`),
    ``policy_kwargs`` and ``env_kwargs`` (the keys the experiment sets itself are refused below, by
    name). Each learned cell's config is the entry with these merged over it, which the config
    loader checks again, whole."""
    from sb3_pm.zoo.checks import check_mapping, check_settings
    from sb3_pm.zoo.schema import KEYS, POLICY_KEYS

    env_kwargs = settings.get("env_kwargs") or {}
    if isinstance(env_kwargs, dict):
        env_kwargs = {k: v for k, v in env_kwargs.items() if k not in _EXPERIMENT_ENV_KEYS}
    try:
        check_settings(settings.get("hyperparams") or {}, f"{where}hyperparams")
        policy_kwargs = settings.get("policy_kwargs") or {}
        check_mapping(policy_kwargs, POLICY_KEYS, f"{where}policy_kwargs", "a policy key")
        check_mapping(env_kwargs, KEYS["env"], f"{where}env_kwargs", "an env key")
    except InputError as error:
        raise _fail(source, str(error)) from None


def _check_removed(settings: dict[str, Any], source: Path, where: str) -> None:
    """Refuse a removed research switch in a variant's settings, its hyperparams and its per-agent
    overrides (:func:`sb3_pm.zoo.config.check_removed`)."""
    from sb3_pm.zoo.config import check_removed

    agents = settings.get("agents")
    parts = [settings, settings.get("hyperparams"), *(agents.values() if isinstance(agents, dict) else ())]
    try:
        for part in parts:
            if isinstance(part, dict):
                check_removed(part, where)
    except InputError as error:
        raise _fail(source, str(error)) from None


def variant_config(
    variant: Variant,
    config: str | Path | None,
    graph: str,
    hyperparams: dict[str, Any],
    env_kwargs: dict[str, Any],
    max_cycles: int,
    n_agents: int,
) -> Any:
    """A learned variant's training config (a :class:`~sb3_pm.zoo.config.TrainConfig`) on
    ``graph``: the entry of its config (the variant's own, else the experiment's ``config``) with,
    merged over it and checked as the file's own keys, the experiment's ``hyperparams`` and then
    the variant's (team keys among them: ``deploy_temperature``, ``deploy_filter``,
    ``learning_rate_spread``, ``n_envs``), the variant's ``policy_kwargs`` (key by key), the
    experiment's and the variant's ``env_kwargs`` with the experiment's ``max_cycles``, the team
    size (``train_agents``, else the experiment's ``n_agents``) and the variant's ``agents``.

    :raises ConfigError: for a merged entry the config loader refuses.
    """
    from sb3_pm.zoo.config import load_config

    source = variant.config or config
    if source is None:
        raise ExperimentError(f"variant {variant.key!r}: learned variants need 'config' (the training YAML)")
    overrides: dict[str, Any] = {**hyperparams, **variant.hyperparams}
    if variant.policy_kwargs:
        overrides["policy_kwargs"] = {**(overrides.get("policy_kwargs") or {}), **variant.policy_kwargs}
    overrides["env_kwargs"] = {
        **(overrides.get("env_kwargs") or {}),
        **env_kwargs,
        **variant.env_kwargs,
        "max_cycles": max_cycles,
    }
    # train_agents: a team trained with that many agents and deployed with the experiment's n_agents
    overrides["n_agents"] = variant.train_agents or n_agents
    if variant.agents:  # replaces the file's own ``agents``, validated against the team size
        overrides["agents"] = variant.agents
    origin = f"the experiment's and variant {variant.key!r}'s settings"
    return load_config(source, variant.train_env or graph, overrides, origin=origin)


def load_experiment(path: str | Path) -> Experiment:
    """Parse and validate an experiment file.

    :param path: an experiment file, or the name of a shipped one (``comparison``).
    :raises FileNotFoundError: if the file is missing.
    :raises ExperimentError: for malformed YAML, unknown keys, bad values or a missing config file.
    """
    from sb3_pm.zoo.shipped import resolve_experiment_path

    path = resolve_experiment_path(path)
    try:
        raw = yaml.safe_load(path.read_text())
    except yaml.YAMLError as error:
        raise _fail(path, f"not valid YAML: {error}") from error
    if not isinstance(raw, dict):
        raise _fail(path, "expected a mapping at the top level")
    unknown = sorted(set(raw) - set(KEYS["experiment"]))
    if unknown:
        raise _fail(path, f"unknown keys {unknown}; allowed: {sorted(KEYS['experiment'])}")
    for key, value in raw.items():
        _check_scalar(key, value, path)
    _check_removed(raw, path, "experiment")
    for key in ("graphs", "seeds", "variants"):
        if not raw.get(key):
            raise _fail(path, f"{key!r} is required and must not be empty")
    variants = []
    if not isinstance(raw["variants"], dict):
        raise _fail(path, "'variants' must map names to settings")
    for key, settings in raw["variants"].items():
        settings = settings or {}
        if not isinstance(settings, dict):
            raise _fail(path, f"variant {key!r} must be a mapping")
        bad = sorted(set(settings) - set(KEYS["variant"]))
        if bad:
            raise _fail(path, f"variant {key!r}: unknown keys {bad}; allowed: {sorted(KEYS['variant'])}")
        kind = settings.get("kind", "independent")
        if kind not in VARIANT_KINDS:
            raise _fail(path, f"variant {key!r}: kind must be one of {VARIANT_KINDS}, got {kind!r}")
        if kind == "baseline" and not settings.get("policy"):
            raise _fail(path, f"variant {key!r}: a baseline needs 'policy'")
        for mapping in ("policy_kwargs", "hyperparams", "env_kwargs", "agents"):
            if not isinstance(settings.get(mapping, {}), dict):
                raise _fail(path, f"variant {key!r}: {mapping!r} must be a mapping")
        _check_removed(settings, path, f"variant {key!r}")
        _check_settings(settings, path, f"variant {key!r}: ")
        clash = sorted(_EXPERIMENT_ENV_KEYS & set(settings.get("env_kwargs", {})))
        if kind == "baseline" and clash:
            raise _fail(
                path,
                f"variant {key!r}: a baseline's env_kwargs must not set {clash}: "
                "use the experiment's graphs, n_agents and max_cycles",
            )
        if clash:  # a learned variant's would be replaced by the experiment's, without a word
            raise _fail(
                path, f"variant {key!r}: env_kwargs must not set {clash}: use the experiment's {clash[0]}"
            )
        train = settings.get("train", True)
        if not isinstance(train, bool):
            raise _fail(path, f"variant {key!r}: 'train' must be true or false, got {train!r}")
        if not train and kind == "baseline":
            raise _fail(path, f"variant {key!r}: 'train' applies to learned variants, not baselines")
        if settings.get("agents") and kind != "independent":
            raise _fail(path, f"variant {key!r}: 'agents' applies to independent variants only")
        train_agents = settings.get("train_agents")
        if train_agents is not None:
            if isinstance(train_agents, bool) or not isinstance(train_agents, int) or train_agents < 1:
                raise _fail(
                    path, f"variant {key!r}: 'train_agents' must be a positive integer, got {train_agents!r}"
                )
            if kind != "independent" or settings.get("train_env") is None:
                raise _fail(
                    path,
                    f"variant {key!r}: 'train_agents' applies to independent variants with a train_env "
                    "(one team per seed, deployed with the experiment's n_agents)",
                )
        team_size = train_agents if train_agents is not None else raw.get("n_agents", 4)
        for agent, values in settings.get("agents", {}).items():
            # Checked here, not only when a cell starts training, so a typo fails before the sweep.
            if isinstance(team_size, int) and agent not in {f"agent_{i}" for i in range(team_size)}:
                raise _fail(
                    path,
                    f"variant {key!r}: agents: unknown agent {agent!r} "
                    f"(the team has agent_0 .. agent_{team_size - 1})",
                )
            if not isinstance(values, dict):
                raise _fail(path, f"variant {key!r}: agents.{agent} must be a mapping of hyperparameters")
        variant_config = settings.get("config")
        if variant_config is not None and kind == "baseline":
            raise _fail(path, f"variant {key!r}: 'config' applies to learned variants, not baselines")
        if variant_config is not None and not (path.parent / str(variant_config)).is_file():
            raise _fail(
                path, f"variant {key!r}: training config not found: {path.parent / str(variant_config)}"
            )
        train_env = settings.get("train_env")
        if train_env is not None:
            if kind != "independent":
                raise _fail(path, f"variant {key!r}: 'train_env' applies to independent variants only")
            from sb3_pm.graphs import resolve_graph_or_family

            try:
                resolve_graph_or_family(str(train_env))
            except (InputError, FileNotFoundError) as error:
                raise _fail(path, f"variant {key!r}: train_env: {error}") from None
        timesteps = settings.get("timesteps")
        if timesteps is not None and (
            kind == "baseline"
            or isinstance(timesteps, bool)
            or not isinstance(timesteps, int)
            or timesteps < 1
        ):
            raise _fail(path, f"variant {key!r}: 'timesteps' must be a positive integer of a learned variant")
        variants.append(
            Variant(
                key=str(key),
                kind=kind,
                label=str(settings.get("label", key)),
                policy=settings.get("policy"),
                policy_kwargs=dict(settings.get("policy_kwargs", {})),
                hyperparams=dict(settings.get("hyperparams", {})),
                env_kwargs=dict(settings.get("env_kwargs", {})),
                train=train,
                config=None if variant_config is None else str(path.parent / str(variant_config)),
                train_env=None if train_env is None else str(train_env),
                timesteps=timesteps,
                agents={str(agent): dict(values) for agent, values in settings.get("agents", {}).items()},
                train_agents=train_agents,
            )
        )
    config = raw.get("config")
    config_path = (path.parent / str(config)) if config else None
    if any(v.learned for v in variants):
        if config_path is None:
            raise _fail(path, "learned variants need 'config' (the training YAML)")
        if not config_path.is_file():
            raise _fail(path, f"training config not found: {config_path}")
    if not isinstance(raw.get("hyperparams", {}) or {}, dict):
        raise _fail(path, "'hyperparams' must be a mapping")
    _check_settings(raw, path, "")
    _check_settings({"env_kwargs": raw.get("eval_env_kwargs")}, path, "eval_")
    quick = raw.get("quick", {}) or {}
    if not isinstance(quick, dict):
        raise _fail(path, "'quick' must be a mapping")
    try:
        experiment = Experiment(
            name=str(raw.get("name", path.stem)),
            graphs=tuple(str(g) for g in raw["graphs"]),
            seeds=tuple(int(s) for s in raw["seeds"]),
            episodes=int(raw.get("episodes", 10)),
            max_cycles=int(raw.get("max_cycles", 500)),
            n_agents=int(raw.get("n_agents", 4)),
            config=config_path,
            timesteps=None if raw.get("timesteps") is None else int(raw["timesteps"]),
            variants=tuple(variants),
            env_kwargs=dict(raw.get("env_kwargs", {}) or {}),
            eval_env_kwargs=dict(raw.get("eval_env_kwargs", {}) or {}),
            hyperparams=dict(raw.get("hyperparams", {}) or {}),
            quick_overrides=dict(quick),
            source=path,
        )
        experiment.quick()  # validate the overrides now rather than at --quick time
    except ExperimentError:
        raise  # already names the file
    except (TypeError, ValueError) as error:
        raise _fail(path, str(error)) from error
    if experiment.episodes < 1:
        raise _fail(path, "'episodes' must be at least 1")
    clash = sorted(_EXPERIMENT_ENV_KEYS & set(experiment.env_kwargs))
    if clash:  # replaced by the experiment's own in every cell, without a word
        raise _fail(path, f"env_kwargs must not set {clash}: use the experiment's {clash[0]}")
    clash = sorted(_EXPERIMENT_ENV_KEYS & set(experiment.eval_env_kwargs))
    if clash:
        raise _fail(
            path,
            f"eval_env_kwargs must not set {clash}: use the experiment's graphs, n_agents and max_cycles",
        )
    return experiment
