"""The record of an experiment as run (``DIR/experiment.yml``): what a resumed sweep must match.

A folder resumes only into the same experiment: the record holds the file's settings and, for
each learned variant, the team keys its config resolves to that change how the team trains or
acts (:func:`team_rules`), since the record names a config by its path only.
"""

from __future__ import annotations

from dataclasses import asdict
from typing import Any

from sb3_pm.evaluation import SEED_STRIDE
from sb3_pm.experiments.spec import Experiment, ExperimentError, variant_config
from sb3_pm.zoo.schema import RECORDED_TEAM_KEYS

#: Evaluation env seeds start here, far from the seeds training episodes use.
EVAL_SEED_OFFSET = 1_000_000


#: Variant fields left out of the record when they hold these defaults.
_RECORD_DEFAULTS: dict[str, Any] = {
    "train": True,
    "config": None,
    "train_env": None,
    "timesteps": None,
    "agents": {},
    "train_agents": None,
}


def team_rules(experiment: Experiment) -> dict[str, Any]:
    """``{key: {variant: value}}`` for the team keys an experiment records
    (:data:`~sb3_pm.zoo.schema.RECORDED_TEAM_KEYS`: how each learned variant acts at deployment and
    how its learners' rates spread), as each variant's config resolves them, where they differ from
    "not set": one value, or ``{graph: value}`` where the graphs' entries differ.

    The record names a config by its path only, so without these an edited ``deploy_temperature``,
    ``deploy_filter`` or ``learning_rate_spread`` would let a resumed folder mix cells trained or
    evaluated both ways.

    :raises ExperimentError: for a centralized variant with a spread (one network, one rate), here
        rather than when its first cell trains.
    """
    rules: dict[str, dict[str, Any]] = {key: {} for key in RECORDED_TEAM_KEYS}
    for variant in experiment.variants:
        source = variant.config or experiment.config
        if not variant.learned or source is None:
            continue
        graphs = [variant.train_env] if variant.train_env else list(experiment.graphs)
        configs = {
            graph: variant_config(
                variant,
                None if experiment.config is None else str(experiment.config),
                graph,
                experiment.hyperparams,
                experiment.env_kwargs,
                experiment.max_cycles,
                experiment.n_agents,
            )
            for graph in graphs
        }
        for key, unset in RECORDED_TEAM_KEYS.items():
            per_graph = {graph: getattr(config, key) for graph, config in configs.items()}
            values = list(per_graph.values())
            if all(value == unset for value in values):
                continue
            if key == "learning_rate_spread" and variant.kind == "centralized":
                raise ExperimentError(
                    f"{experiment.source}: variant {variant.key!r}: a centralized team has one learning "
                    f"rate, but its config spreads them ({source}); pin hyperparams: "
                    "{learning_rate_spread: 1}"
                )
            rules[key][variant.key] = values[0] if all(v == values[0] for v in values) else per_graph
    return {key: value for key, value in rules.items() if value}


def experiment_record(experiment: Experiment) -> dict[str, Any]:
    # eval_env_kwargs is recorded only when set (folders written before it existed resume), so a
    # changed deployment condition is a different experiment and never reuses finished cells;
    # likewise the learned variants' recorded team keys (team_rules).
    extra: dict[str, Any] = (
        {"eval_env_kwargs": experiment.eval_env_kwargs} if experiment.eval_env_kwargs else {}
    )
    extra.update(team_rules(experiment))
    return {
        **extra,
        "name": experiment.name,
        "graphs": list(experiment.graphs),
        "seeds": list(experiment.seeds),
        "episodes": experiment.episodes,
        "max_cycles": experiment.max_cycles,
        "n_agents": experiment.n_agents,
        "config": None if experiment.config is None else str(experiment.config),
        "timesteps": experiment.timesteps,
        "env_kwargs": experiment.env_kwargs,
        "hyperparams": experiment.hyperparams,
        "evaluation_seeds": f"{EVAL_SEED_OFFSET} + seed * {SEED_STRIDE} + episode",
        # ``train`` and ``config`` are recorded only when set, so folders written before these keys
        # existed resume.
        "variants": {
            v.key: {
                k: val
                for k, val in asdict(v).items()
                if k != "key" and not (k in _RECORD_DEFAULTS and val == _RECORD_DEFAULTS[k])
            }
            for v in experiment.variants
        },
    }


__all__ = ["EVAL_SEED_OFFSET", "experiment_record", "team_rules"]
