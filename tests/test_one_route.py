"""One saved team, one way to act: every route that evaluates it gives the same metrics.

The team is trained by a sweep cell (``sb3-pm reproduce``'s runner) with env settings that change
what its agents see (``graph_knowledge: known``) and a ``deploy_filter`` (a territory bound). The
cell's own evaluation, Python's ``evaluate()`` and ``compare()``, ``sb3-pm evaluate`` and
``sb3-pm compare`` then run it on the same episodes; each must act in the env it was trained in,
under its filter, and give the same per-episode metrics.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from sb3_pm.evaluation import SEED_STRIDE, compare, evaluate
from sb3_pm.evaluation.teams import load_trained_team
from sb3_pm.experiments import load_experiment, reproduce
from sb3_pm.experiments.runner import EVAL_SEED_OFFSET, plan_cells

STEPS, EPISODES = 30, 2
#: The env seeds of the sweep's evaluation of seed 0 (``compare`` seed ``s`` starts at ``s * SEED_STRIDE``).
EVAL_SEED = EVAL_SEED_OFFSET
COMPARE_SEED = EVAL_SEED // SEED_STRIDE


@pytest.fixture(scope="module")
def swept_team(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, list[dict]]:
    """``(team folder, graph file, the cell's per-episode records)`` of a one-cell sweep."""
    from sb3_pm.graphs import erdos_renyi, save_graphml

    root = tmp_path_factory.mktemp("route")
    graph = save_graphml(erdos_renyi(14, 0.3, n_targets=4, seed=3), root / "site.graphml")
    (root / "config.yml").write_text(
        "default:\n  n_timesteps: 64\n  n_envs: 1\n  n_steps: 32\n  batch_size: 32\n  n_epochs: 1\n"
        "  policy_kwargs: {hidden_dim: 8, gat_heads: 1}\n"
        "  env_kwargs: {graph_knowledge: known}\n"
        "  deploy_filter: {neglect_bound: 12, neglect_scope: territory}\n"
    )
    (root / "experiment.yml").write_text(
        f"name: route\ngraphs: [{graph}]\nseeds: [0]\nepisodes: {EPISODES}\nmax_cycles: {STEPS}\n"
        "n_agents: 2\nconfig: config.yml\nvariants:\n  learned: {}\n"
    )
    experiment = load_experiment(root / "experiment.yml")
    reproduce(experiment, root / "sweep", n_jobs=1, progress=False)
    (cell,) = plan_cells(experiment, root / "sweep")
    records = json.loads((Path(cell.folder) / "evaluation.json").read_text())["episodes"]
    return Path(cell.folder) / "team", graph, records


def _metrics(records: list[dict]) -> list[dict]:
    """Per-episode metrics and env seeds, without the label fields."""
    return [{k: v for k, v in r.items() if k not in ("episode", "team_seed")} for r in records]


def test_the_team_records_its_env_and_filter(swept_team) -> None:
    team_folder, graph, _ = swept_team
    team = load_trained_team(team_folder, graph)
    assert team.env_settings()["graph_knowledge"] == "known"
    assert team.deploy_filter == {"neglect_bound": 12.0, "neglect_scope": "territory"}
    assert team.acting_filter() == {"neglect_bound": 12.0, "neglect_scope": "territory"}
    env = team.make_env(max_cycles=STEPS)  # the env it acts in: its own graph, size and settings
    assert env.unwrapped.graph.fingerprint == team.graph.fingerprint
    assert env.unwrapped.graph_knowledge == "known" and len(env.possible_agents) == 2
    env.close()


def test_every_route_gives_the_sweep_cells_metrics(swept_team, tmp_path: Path, capsys) -> None:
    from sb3_pm.cli import main

    team_folder, graph, cell_records = swept_team
    expected = _metrics(cell_records)
    assert [r["seed"] for r in expected] == [EVAL_SEED, EVAL_SEED + 1]

    python = evaluate(
        load_trained_team(team_folder), graph, episodes=EPISODES, seed=EVAL_SEED, max_cycles=STEPS
    )
    assert _metrics([r.to_dict() for r in python.episodes]) == expected
    assert python.config["neglect_bound"] == 12.0
    own = evaluate(load_trained_team(team_folder), episodes=EPISODES, seed=EVAL_SEED, max_cycles=STEPS)
    assert _metrics([r.to_dict() for r in own.episodes]) == expected  # its own graph and size

    compared = compare(
        {"team": lambda g: load_trained_team(team_folder, g)},
        [str(graph)],
        seeds=[COMPARE_SEED],
        episodes=EPISODES,
        max_cycles=STEPS,
    )
    assert _metrics([r.to_dict() for r in compared.results["team"][0].episodes]) == expected

    out = tmp_path / "evaluate.json"
    argv = ["--policy", str(team_folder), "--graph", str(graph), "--episodes", str(EPISODES)]
    argv += ["--seed", str(EVAL_SEED), "--steps", str(STEPS), "--json", str(out), "--no-progress"]
    assert main(["evaluate", *argv]) == 0
    assert _metrics(json.loads(out.read_text())["episodes"]) == expected

    report = tmp_path / "compare"
    argv = ["--policies", str(team_folder), "--graphs", str(graph), "--seeds", str(COMPARE_SEED)]
    argv += ["--episodes", str(EPISODES), "--steps", str(STEPS), "--out", str(report), "--no-progress"]
    assert main(["compare", *argv]) == 0
    (records,) = json.loads((report / "results.json").read_text())["results"].values()
    assert _metrics(records[0]["episodes"]) == expected
    capsys.readouterr()


def test_the_settings_matter_so_the_check_can_fail(swept_team) -> None:
    """The same episodes in the default env (maps discovered, no bound) give other metrics: the
    equality above holds because every route builds the team's own env and filter."""
    team_folder, graph, cell_records = swept_team
    team = load_trained_team(team_folder)
    team.set_filter(neglect_bound=None)
    other = evaluate(
        team,
        graph,
        episodes=EPISODES,
        seed=EVAL_SEED,
        max_cycles=STEPS,
        env_kwargs={"graph_knowledge": "discovered"},
    )
    assert _metrics([r.to_dict() for r in other.episodes]) != _metrics(cell_records)
