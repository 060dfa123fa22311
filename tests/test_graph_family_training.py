"""Training on a graph family: seeded draws, padded observations, and the teams trained on them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch as th
from pettingzoo.test import parallel_api_test

from sb3_pm.agents.deployment.transfer import TransferredTeam, rebuild_policy
from sb3_pm.agents.training.team import IndependentPPO
from sb3_pm.envs import persistent_monitoring_v0
from sb3_pm.errors import InputError
from sb3_pm.evaluation import evaluate, resolve_team
from sb3_pm.graphs import GraphError, erdos_renyi, save_graphml
from sb3_pm.graphs.distributions import (
    ErdosRenyiFamily,
    FolderFamily,
    MixtureFamily,
    RandomGeometricFamily,
    RoomsFamily,
    family_from_record,
    resolve_family,
)
from tests.conftest import path_graph

SMALL = ErdosRenyiFamily(n_nodes_range=(8, 14), edge_prob=(0.25, 0.4), name="small-er")
TINY = {"n_steps": 20, "batch_size": 20, "n_epochs": 1, "policy_kwargs": {"laplacian": "none"}}


def graph_sequence(env, seeds: list[int | None]) -> list[str]:
    names = []
    for seed in seeds:
        env.reset(seed=seed)
        names.append(env.graph.fingerprint)
    return names


# ------------------------------------------------------------------ families
@pytest.mark.parametrize("name", ["er", "rgg", "rooms", "mixed"])
def test_family_draws_are_deterministic_per_seed(name: str) -> None:
    family = resolve_family(f"family:{name}")
    draws = [[family.draw(np.random.default_rng(seed)).fingerprint for _ in range(1)] for seed in (3, 3, 4)]
    rng_a, rng_b = np.random.default_rng(7), np.random.default_rng(7)
    sequence_a = [family.draw(rng_a) for _ in range(5)]
    sequence_b = [family.draw(rng_b) for _ in range(5)]
    assert [g.fingerprint for g in sequence_a] == [g.fingerprint for g in sequence_b]
    assert draws[0] == draws[1] and draws[0] != draws[2]
    assert all(g.n_nodes <= family.max_nodes for g in sequence_a)
    assert len({g.fingerprint for g in sequence_a}) > 1  # a family, not one graph


def test_family_draws_stay_in_their_ranges() -> None:
    rng = np.random.default_rng(0)
    for _ in range(30):
        graph = SMALL.draw(rng)
        assert 8 <= graph.n_nodes <= 14 and graph.n_targets >= 2
    rooms = RoomsFamily(n_rooms=(2, 3), room_width=(3, 3), room_depth=(2, 2))
    assert {rooms.draw(rng).n_nodes for _ in range(20)} == {12, 18}


def test_a_family_record_rebuilds_the_same_family(tmp_path: Path) -> None:
    save_graphml(path_graph(5, [0]), tmp_path / "a.graphml")
    save_graphml(erdos_renyi(7, 0.5, n_targets=2, seed=1), tmp_path / "b.graphml")
    families = [
        SMALL,
        RandomGeometricFamily(n_nodes_range=(10, 20)),
        MixtureFamily(members=(SMALL, RoomsFamily())),
        FolderFamily(folder=str(tmp_path)),
    ]
    for family in families:
        rebuilt = family_from_record(family.record())
        assert rebuilt.fingerprint == family.fingerprint and rebuilt.max_nodes == family.max_nodes
        assert rebuilt.draw(np.random.default_rng(1)).same_problem(family.draw(np.random.default_rng(1)))
    assert families[0].fingerprint != ErdosRenyiFamily().fingerprint


def test_a_folder_family_draws_its_files(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    save_graphml(path_graph(5, [0]), tmp_path / "a.graphml")
    save_graphml(erdos_renyi(7, 0.5, n_targets=2, seed=1), tmp_path / "b.graphml")
    family = resolve_family(f"family:{tmp_path}")
    assert (family.min_nodes, family.max_nodes) == (5, 7)
    assert {family.draw(np.random.default_rng(s)).n_nodes for s in range(20)} == {5, 7}
    # A relative folder is recorded absolute: a saved team finds it from any working directory.
    monkeypatch.chdir(tmp_path.parent)
    relative = resolve_family(f"family:{tmp_path.name}")
    assert relative.record()["folder"] == str(tmp_path.resolve())


@pytest.mark.parametrize(
    "value, message",
    [
        ("family:nope", r"unknown graph family 'family:nope': use family:er, family:rgg"),
        ("family:/no/such/folder", r"graph family folder /no/such/folder is not a folder"),
        ("paper-50", r"'paper-50' is not a graph family"),
    ],
)
def test_bad_family_names_are_one_line_errors(value: str, message: str) -> None:
    with pytest.raises(GraphError, match=message):
        resolve_family(value)


def test_an_empty_folder_and_bad_ranges_are_refused(tmp_path: Path) -> None:
    with pytest.raises(GraphError, match="holds no .graphml file"):
        FolderFamily(folder=str(tmp_path))
    with pytest.raises(GraphError, match=r"edge_prob must satisfy"):
        ErdosRenyiFamily(edge_prob=(0.5, 0.2))
    with pytest.raises(GraphError, match=r"n_nodes_range must be a \(low, high\) pair of integers"):
        ErdosRenyiFamily(n_nodes_range=(10.7, 20.2))  # type: ignore[arg-type]
    with pytest.raises(GraphError, match=r"edge_prob must be a \(low, high\) pair of numbers"):
        ErdosRenyiFamily(edge_prob=("a", "b"))  # type: ignore[arg-type]
    with pytest.raises(GraphError, match=r"degree must satisfy 4.0 <= low"):
        RandomGeometricFamily(degree=(1, 2))
    with pytest.raises(GraphError, match="unknown graph family kind"):
        family_from_record({"kind": "spiral"})


# ----------------------------------------------------------------------- env
def test_each_reset_draws_a_graph_from_the_seed() -> None:
    env = persistent_monitoring_v0.parallel_env(graph=SMALL, n_agents=2, max_cycles=5)
    other = persistent_monitoring_v0.parallel_env(graph=SMALL, n_agents=2, max_cycles=5)
    first = graph_sequence(env, [11, None, None, None])
    assert first == graph_sequence(other, [11, None, None, None])
    assert len(set(first)) > 1
    assert graph_sequence(other, [12, None, None, None]) != first


def test_family_env_passes_the_pettingzoo_api_test() -> None:
    parallel_api_test(
        persistent_monitoring_v0.parallel_env(graph=SMALL, n_agents=3, max_cycles=20), num_cycles=60
    )


def test_observations_are_padded_to_the_family_size() -> None:
    env = persistent_monitoring_v0.parallel_env(graph=SMALL, n_agents=2, max_cycles=5)
    assert env.observation_space("agent_0")["nodes"].shape == (14, 5)
    for seed in range(6):
        observations, _ = env.reset(seed=seed)
        n = env.graph.n_nodes
        for obs in observations.values():
            assert env.observation_space("agent_0").contains(obs)
            assert not obs["nodes"][n:].any() and not obs["adjacency"][n:].any()
            assert not obs["adjacency"][:, n:].any() and not obs["action_mask"][n:].any()
            assert obs["action_mask"][obs["position"]] == 1


def test_a_move_to_a_padding_node_is_illegal() -> None:
    env = persistent_monitoring_v0.parallel_env(graph=SMALL, n_agents=2, max_cycles=5)
    seed = next(s for s in range(50) if (env.reset(seed=s), env.graph.n_nodes < 14)[1])
    env.reset(seed=seed)
    with pytest.raises(InputError, match="cannot move to node 13"):
        env.step({"agent_0": 13, "agent_1": int(env.positions[1])})


def test_mental_maps_start_empty_on_each_new_graph() -> None:
    env = persistent_monitoring_v0.parallel_env(graph=SMALL, n_agents=2, max_cycles=5)
    observations, _ = env.reset(seed=0)
    for _ in range(5):
        actions = {a: int(np.flatnonzero(o["action_mask"])[-1]) for a, o in observations.items()}
        observations, *_ = env.step(actions)
    observations, _ = env.reset()
    for i, obs in enumerate(observations.values()):
        position = int(obs["position"])
        # Only the edges at the start node are known: none carried over from the last graph.
        known = obs["adjacency"].astype(bool)
        seen = np.zeros_like(known)
        seen[position, : env.graph.n_nodes] = env.graph.adjacency[position]
        seen[: env.graph.n_nodes, position] = env.graph.adjacency[:, position]
        assert np.array_equal(known, seen), f"agent {i}"


def test_family_options_that_need_one_graph_are_refused() -> None:
    with pytest.raises(InputError, match="initial_positions cannot be given with a graph family"):
        persistent_monitoring_v0.parallel_env(graph=SMALL, n_agents=2, initial_positions=[0, 1])
    env = persistent_monitoring_v0.parallel_env(graph=SMALL, n_agents=2)
    with pytest.raises(InputError, match="initial_positions cannot be given with a graph family"):
        env.reset(seed=0, options={"initial_positions": [0, 1]})
    with pytest.raises(
        InputError, match="9 agents do not fit the graph family 'small-er': its smallest graph has 8"
    ):
        persistent_monitoring_v0.parallel_env(graph=SMALL, n_agents=9)
    from sb3_pm.graphs import resolve_graph

    with pytest.raises(GraphError, match="'family:er' is a graph family, which only training takes"):
        resolve_graph("family:er")
    with pytest.raises(InputError, match="a graph family needs observation='map'"):
        persistent_monitoring_v0.parallel_env(graph="family:er", observation="local")


# ------------------------------------------------------------------- policy
def test_padding_does_not_change_the_actor_on_real_nodes() -> None:
    team = IndependentPPO(SMALL, n_agents=2, seed=0, env_kwargs={"max_cycles": 30}, hyperparams=TINY)
    policy = team.models["agent_0"].policy
    graph = erdos_renyi(10, 0.35, n_targets=3, seed=5)
    env = persistent_monitoring_v0.parallel_env(graph=graph, n_agents=2, max_cycles=30)
    rebuilt = rebuild_policy(policy, env.observation_space("agent_0"), env.action_space("agent_0"))
    observations, _ = env.reset(seed=1)
    for _ in range(8):
        obs = observations["agent_0"]
        padded = {
            "nodes": np.pad(obs["nodes"], ((0, 4), (0, 0))),
            "adjacency": np.pad(obs["adjacency"], ((0, 4), (0, 4))),
            "position": obs["position"],
            "dwell": obs["dwell"],
            "action_mask": np.pad(obs["action_mask"], (0, 4)),
        }
        with th.no_grad():
            pre_small = rebuilt._preprocess(rebuilt.obs_to_tensor(obs)[0])
            pre_padded = policy._preprocess(policy.obs_to_tensor(padded)[0])
            # Every real node's logit, not only the allowed ones: the padded nodes are masked out.
            real = th.ones((1, 10), dtype=th.bool)
            small = rebuilt._logits(pre_small, rebuilt.uncertainty(pre_small), real)
            large = policy._logits(
                pre_padded, policy.uncertainty(pre_padded), th.nn.functional.pad(real, (0, 4))
            )
        th.testing.assert_close(large[:, :10], small, rtol=1e-5, atol=1e-5)
        actions = {a: int(np.flatnonzero(o["action_mask"])[-1]) for a, o in observations.items()}
        observations, *_ = env.step(actions)


# --------------------------------------------------------------------- teams
@pytest.fixture(scope="module")
def family_team(tmp_path_factory: pytest.TempPathFactory) -> Path:
    team = IndependentPPO(SMALL, n_agents=2, seed=0, env_kwargs={"max_cycles": 30}, hyperparams=TINY)
    team.learn(60)
    folder = tmp_path_factory.mktemp("family") / "team"
    team.save(folder)
    return folder


@pytest.mark.parametrize(
    "graph",
    [erdos_renyi(9, edge_prob=0.4, n_targets=2, seed=1), path_graph(25, [0, 12, 24]), "rooms-4"],
    ids=["er-9", "path-25", "rooms-4"],
)
def test_a_family_team_acts_legally_on_graphs_it_never_saw(family_team: Path, graph) -> None:
    team = resolve_team(family_team, graph=graph)
    assert isinstance(team, TransferredTeam)
    result = evaluate(team, graph, n_agents=2, episodes=1, max_cycles=20)
    assert result.mean["steps"] == 20


def test_a_saved_family_team_records_and_reloads_its_family(family_team: Path) -> None:
    team = IndependentPPO.load(family_team)
    assert team.graph.fingerprint == SMALL.fingerprint
    with pytest.raises(InputError, match="trained on the graph family 'small-er'; load it without a graph"):
        IndependentPPO.load(family_team, graph="paper-50")
    env = persistent_monitoring_v0.parallel_env(graph="paper-50", n_agents=2, max_cycles=5)
    env.reset(seed=0)
    with pytest.raises(InputError, match=r"deploy it on graph 'paper-50' with team.on_graph"):
        team.reset(env, seed=0)


def test_family_training_gives_the_same_parameters_for_the_same_seed() -> None:
    def train() -> list[th.Tensor]:
        team = IndependentPPO(SMALL, n_agents=2, seed=3, env_kwargs={"max_cycles": 30}, hyperparams=TINY)
        team.learn(60)
        return [p.detach().clone() for p in team.models["agent_1"].policy.parameters()]

    for a, b in zip(train(), train(), strict=True):
        assert th.equal(a, b)


def test_a_family_team_that_cannot_transfer_is_refused_before_training() -> None:
    with pytest.raises(
        InputError, match=r"family 'small-er' must transfer: .*Laplacian-rows encoding .* N = 14"
    ):
        IndependentPPO(
            SMALL, n_agents=2, env_kwargs={"max_cycles": 30}, hyperparams={**TINY, "policy_kwargs": {}}
        )


def test_a_folder_family_whose_files_changed_is_refused_on_load(tmp_path: Path) -> None:
    graphs = tmp_path / "graphs"
    graphs.mkdir()
    save_graphml(erdos_renyi(8, 0.5, n_targets=2, seed=1), graphs / "a.graphml")
    team = IndependentPPO(f"family:{graphs}", n_agents=2, env_kwargs={"max_cycles": 10}, hyperparams=TINY)
    team.save(tmp_path / "team")
    save_graphml(erdos_renyi(9, 0.5, n_targets=2, seed=2), graphs / "b.graphml")
    with pytest.raises(InputError, match=r"trained on the graph family .* which now rebuilds as family-"):
        IndependentPPO.load(tmp_path / "team")


def test_a_centralized_team_refuses_a_family() -> None:
    from sb3_pm.sharing.centralized import CentralizedPPO

    with pytest.raises(InputError, match="CentralizedPPO trains on one graph, not on the graph family"):
        CentralizedPPO(SMALL, n_agents=2)
