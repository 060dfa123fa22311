"""Zero-shot transfer of a trained team to graphs of other sizes (sb3_pm.agents.deployment.transfer)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch as th

from sb3_pm.agents.deployment.transfer import TransferredTeam, rebuild_policy
from sb3_pm.agents.training.team import IndependentPPO
from sb3_pm.envs import persistent_monitoring_v0
from sb3_pm.evaluation import evaluate, resolve_team
from sb3_pm.evaluation.teams import PolicyError
from sb3_pm.graphs import erdos_renyi
from tests.conftest import path_graph

TRAIN_GRAPH = erdos_renyi(16, edge_prob=0.25, n_targets=3, seed=2, name="train16")


def small_team(laplacian: str) -> IndependentPPO:
    team = IndependentPPO(
        TRAIN_GRAPH,
        n_agents=2,
        seed=0,
        env_kwargs={"max_cycles": 40},
        hyperparams={
            "n_steps": 20,
            "batch_size": 20,
            "n_epochs": 1,
            "policy_kwargs": {"laplacian": laplacian},
        },
    )
    team.learn(40)
    return team


@pytest.fixture(scope="module")
def saved_transferable(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("teams") / "none"
    small_team("none").save(folder)
    return folder


@pytest.mark.parametrize(
    "graph",
    [erdos_renyi(9, edge_prob=0.4, n_targets=2, seed=1), path_graph(25, [0, 12, 24]), "paper-50"],
    ids=["er-9", "path-25", "paper-50"],
)
def test_a_transferable_team_acts_legally_on_graphs_of_other_sizes(saved_transferable: Path, graph) -> None:
    team = resolve_team(saved_transferable, graph=graph)
    assert isinstance(team, TransferredTeam)
    # The env raises on any illegal move; 3 agents from a 2-agent team also exercise learner_for.
    result = evaluate(team, graph, n_agents=3, episodes=1, max_cycles=30)
    assert result.mean["steps"] == 30


def test_on_its_own_graph_the_team_is_itself(saved_transferable: Path) -> None:
    team = IndependentPPO.load(saved_transferable)
    assert team.on_graph(TRAIN_GRAPH) is team


def test_a_rebuilt_policy_computes_what_the_trained_one_does(saved_transferable: Path) -> None:
    team = IndependentPPO.load(saved_transferable)
    policy = team.models["agent_0"].policy
    rebuilt = rebuild_policy(policy, policy.observation_space, policy.action_space)
    env = persistent_monitoring_v0.parallel_env(graph=TRAIN_GRAPH, n_agents=2, max_cycles=40)
    observations, _ = env.reset(seed=3)
    for _ in range(5):
        obs = observations["agent_0"]
        tensor, _ = policy.obs_to_tensor(obs)
        with th.no_grad():
            pre_a, pre_b = policy._preprocess(tensor), rebuilt._preprocess(tensor)
            every = th.ones_like(pre_a["action_mask"], dtype=th.bool)  # every node's logit
            a = policy._logits(pre_a, policy.uncertainty(pre_a), every)
            b = rebuilt._logits(pre_b, rebuilt.uncertainty(pre_b), every)
        assert th.equal(a, b)
        actions = {agent: int(np.flatnonzero(o["action_mask"])[0]) for agent, o in observations.items()}
        observations, *_ = env.step(actions)


def test_a_team_tied_to_its_graph_size_refuses_with_the_reason(tmp_path: Path) -> None:
    folder = tmp_path / "rows"
    small_team("rows").save(folder)
    with pytest.raises(PolicyError, match=r"Laplacian-rows encoding .* ties its first GAT layer to N = 16"):
        resolve_team(folder, graph="paper-50")
    # On its own graph it loads as before.
    assert isinstance(resolve_team(folder, graph=TRAIN_GRAPH), IndependentPPO)


def test_a_transferred_team_refuses_a_third_graph(saved_transferable: Path) -> None:
    team = resolve_team(saved_transferable, graph="paper-50")
    env = persistent_monitoring_v0.parallel_env(graph=path_graph(6, [0]), n_agents=2, max_cycles=5)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="not on graph 'path'.*rebuilt for graph 'paper-50'"):
        team.reset(env, seed=0)


BOUND_GRAPH = path_graph(25, [0, 6, 12, 18, 24])


def test_a_moved_team_takes_a_territory_bound_on_its_new_graph(saved_transferable: Path) -> None:
    from sb3_pm.errors import InputError
    from sb3_pm.graphs.territories import agent_territories

    team = resolve_team(saved_transferable, graph=BOUND_GRAPH)
    assert isinstance(team, TransferredTeam) and team.acting_filter() is None
    team.set_filter(neglect_bound=20.0, neglect_scope="territory")
    assert [p.dcbf_config.territory for p in team.policies.values()] == agent_territories(BOUND_GRAPH, 2)
    assert team.acting_filter() == {"neglect_bound": 20.0, "neglect_scope": "territory"}
    # The trained team it came from keeps its own filter.
    assert all(m.policy.dcbf_config.neglect_bound is None for m in team.source.models.values())
    # A setting it cannot take changes nothing.
    with pytest.raises(InputError, match="above the environment's u_max"):
        team.set_filter(neglect_bound=1000.0)
    with pytest.raises(InputError, match="must be at least 1"):  # raised as the new configs are built
        team.set_filter(neglect_bound=0.5)
    assert team.acting_filter() == {"neglect_bound": 20.0, "neglect_scope": "territory"}
    result = evaluate(team, BOUND_GRAPH, n_agents=2, episodes=1, max_cycles=60)
    assert (result.config["neglect_bound"], result.config["neglect_scope"]) == (20.0, "territory")
    assert team.filter_activity()["masks"] == 2 * 60  # every agent-step ran under the bound
    team.set_filter(neglect_bound=None)
    assert team.acting_filter() is None


def test_evaluate_deploys_a_moved_team_under_a_bound(saved_transferable: Path, tmp_path: Path) -> None:
    import json

    from sb3_pm.cli import main
    from sb3_pm.graphs.io import save_graphml

    graph = save_graphml(BOUND_GRAPH, tmp_path / "path25.graphml")
    out = tmp_path / "e.json"
    argv = ["evaluate", "--policy", str(saved_transferable), "--graph", str(graph), "--agents", "2"]
    flags = ["--episodes", "1", "--steps", "60", "--neglect-bound", "20", "--neglect-scope", "territory"]
    assert main([*argv, *flags, "--json", str(out)]) == 0
    config = json.loads(out.read_text())["config"]
    assert (config["neglect_bound"], config["neglect_scope"]) == (20.0, "territory")
    assert config["filter_activity"]["masks"] == 120


def test_a_moved_team_bounds_each_episodes_planned_groups_with_one_learner_per_agent(
    saved_transferable: Path,
) -> None:
    from sb3_pm.errors import InputError

    team = resolve_team(saved_transferable, graph=BOUND_GRAPH)
    team.set_filter(neglect_bound=20.0, neglect_scope="territory")

    def planned_env(n_agents: int):
        return persistent_monitoring_v0.parallel_env(
            graph=BOUND_GRAPH, n_agents=n_agents, max_cycles=20, territories="planned",
            advice_input=True, graph_knowledge="known", target_knowledge="known",
        )

    env = planned_env(2)
    env.reset(seed=0)
    team.reset(env, seed=0)
    planned = [tuple(np.flatnonzero(row).tolist()) for row in env.unwrapped._territory]
    assert [p.dcbf_config.territory for p in team.policies.values()] == planned
    # Shared learners cannot each guard one agent's group: refused in one line.
    env = planned_env(3)
    env.reset(seed=0)
    with pytest.raises(InputError, match="needs one learner per agent") as error:
        team.reset(env, seed=0)
    assert "\n" not in str(error.value)
    team.set_filter(neglect_bound=None)
    team.reset(env, seed=0)  # without the bound it acts there
