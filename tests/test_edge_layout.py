"""The env's ``layout="edges"``: map observations that grow with the edges, not with N x N.

The edges layout must be the dense layout in another form: the same nodes, masks and known edges at
every step, the same policy outputs on the same maps, PettingZoo's API tests, a rollout buffer that
trains, and a saved state that restores. None of its per-step tables may be ``(N, N)``.
"""

from __future__ import annotations

import copy
import functools
import pickle

import numpy as np
import pytest
import torch as th
from pettingzoo.test import api_test, parallel_api_test
from scipy import sparse

from sb3_pm.agents.training.team import IndependentPPO
from sb3_pm.envs import persistent_monitoring_v0
from sb3_pm.envs.known_edges import SparseRows, balls, edge_list
from sb3_pm.envs.persistent_monitoring import PersistentMonitoringEnv
from sb3_pm.envs.single_agent import SingleAgentMonitoringEnv
from sb3_pm.errors import InputError
from sb3_pm.graphs import erdos_renyi
from sb3_pm.policies import DCBFActorCriticPolicy
from sb3_pm.policies.edges import batched_edges, edges_to_adjacency

th.set_num_threads(1)
SMALL = erdos_renyi(20, 0.2, n_targets=4, seed=3)
#: A sparse graph above the dense kernel's always-dense size (64 nodes), so batches of more than
#: 8 maps take the sparse kernel on the edge list itself.
SPARSE = erdos_renyi(80, 0.03, n_targets=5, seed=2)


def known_dense(observation: dict) -> np.ndarray:
    """``(N, N)`` int8: the known adjacency an edges-layout observation describes."""
    edge_index, mask = observation["edge_index"], observation["edge_mask"] != 0
    dense = np.zeros((len(observation["nodes"]), len(observation["nodes"])), dtype=np.int8)
    dense[edge_index[0, mask], edge_index[1, mask]] = 1
    return dense


@pytest.mark.parametrize(
    "graph,settings",
    [
        ("paper-50", {}),
        ("paper-50", {"graph_knowledge": "known"}),
        (SMALL, {"obs_radius": 2}),
        (SMALL, {"obs_radius": 0}),
        (SMALL, {"shared_map": True}),
        (SMALL, {"failures": {"agent_1": 7}}),
    ],
    ids=["paper50", "paper50-known", "small-r2", "small-r0", "small-shared", "small-failure"],
)
def test_both_layouts_step_alike(graph, settings) -> None:
    dense = PersistentMonitoringEnv(graph, n_agents=3, max_cycles=40, **settings)
    edges = PersistentMonitoringEnv(graph, n_agents=3, max_cycles=40, layout="edges", **settings)
    assert dense.maps.known_edges is None and edges.maps.adjacency is None
    space = edges.observation_space("agent_0")
    assert "adjacency" not in space.spaces and space["edge_index"].shape == (2, 2 * edges.graph.n_edges)
    obs_d, _ = dense.reset(seed=1)
    obs_e, _ = edges.reset(seed=1)
    rng = np.random.default_rng(0)
    for step in range(40):
        assert obs_d.keys() == obs_e.keys()
        for agent in obs_d:
            for key in ("nodes", "position", "dwell", "action_mask"):
                np.testing.assert_array_equal(obs_d[agent][key], obs_e[agent][key], err_msg=f"{step} {key}")
            np.testing.assert_array_equal(known_dense(obs_e[agent]), obs_d[agent]["adjacency"])
            assert space.contains(obs_e[agent]), (step, agent)
        # the maps' sparse store is the dense one's nonzeros
        np.testing.assert_array_equal(edges.maps.known_edges.dense(edges.graph.n_nodes), dense.maps.adjacency)
        actions = {a: int(rng.choice(np.flatnonzero(obs_d[a]["action_mask"]))) for a in dense.agents}
        obs_d, rewards_d, *_ = dense.step(actions)
        obs_e, rewards_e, *_ = edges.step(actions)
        assert rewards_d == rewards_e
        if not dense.agents:
            break
    assert dense.episode_metrics() == edges.episode_metrics()


def test_the_edges_layout_builds_no_all_pairs_table() -> None:
    graph = erdos_renyi(20, 0.2, n_targets=4, seed=3)  # a fresh spec: SMALL's caches may be filled
    env = PersistentMonitoringEnv(graph, n_agents=2, max_cycles=10, layout="edges", obs_radius=2)
    env.reset(seed=0)
    env.step({a: int(env.positions[i]) for i, a in enumerate(env.possible_agents)})
    for cached in ("hop_distances", "reachable", "next_hop"):
        assert cached not in env.graph.__dict__, f"the edges layout computed graph.{cached}"
    for table in (env._observes, env._edge_nodes, env._reachable_i8):
        assert isinstance(table, SparseRows)
    hops = SMALL.hop_distances
    np.testing.assert_array_equal(env._observes.toarray(), hops <= 2)
    np.testing.assert_array_equal(env._edge_nodes.toarray(), hops <= 1)
    np.testing.assert_array_equal(env._reachable_i8.toarray(), SMALL.reachable.astype(np.int8))
    assert balls(sparse.csr_matrix((3, 3), dtype=np.int32), -1).nnz == 0  # obs_radius 0 sees no edges


def test_edge_list_is_the_adjacency_in_row_major_order() -> None:
    edge_index, indptr, reverse = edge_list(SMALL.adjacency)
    rows, cols = np.nonzero(SMALL.adjacency)
    np.testing.assert_array_equal(edge_index, np.stack((rows, cols)))
    np.testing.assert_array_equal(edge_index[:, reverse], edge_index[::-1])
    assert indptr[-1] == edge_index.shape[1]


def test_state_pickle_and_deepcopy_carry_the_known_edges() -> None:
    env = PersistentMonitoringEnv(SMALL, n_agents=3, max_cycles=30, layout="edges")
    env.reset(seed=4)
    rng = np.random.default_rng(1)

    def run(target: PersistentMonitoringEnv, moves: np.random.Generator, steps: int) -> list:
        seen = []
        for _ in range(steps):
            observations = target._observations()
            masks = {a: np.flatnonzero(observations[a]["action_mask"]) for a in target.agents}
            actions = {a: int(moves.choice(legal)) for a, legal in masks.items()}
            obs, *_ = target.step(actions)
            seen.append({a: (o["edge_mask"].tolist(), o["nodes"].tolist()) for a, o in obs.items()})
        return seen

    run(env, rng, 10)
    restored = PersistentMonitoringEnv(SMALL, n_agents=3, max_cycles=30, layout="edges")
    restored.load_state_dict(env.state_dict())
    copies = [restored, copy.deepcopy(env), pickle.loads(pickle.dumps(env))]
    state = rng.bit_generator.state
    expected = run(env, rng, 15)
    for duplicate in copies:
        assert not duplicate._observations()["agent_0"]["edge_mask"].flags.writeable
        rng.bit_generator.state = state
        assert run(duplicate, rng, 15) == expected
    dense = PersistentMonitoringEnv(SMALL, n_agents=3, max_cycles=30)
    with pytest.raises(InputError, match="layout"):
        dense.load_state_dict(env.state_dict())


def test_new_lifetime_forgets_the_known_edges() -> None:
    env = PersistentMonitoringEnv(SMALL, n_agents=2, max_cycles=10, layout="edges")
    observations, _ = env.reset(seed=0)
    assert observations["agent_0"]["edge_mask"].any()
    assert env.maps.known_edges.known.any()
    env.maps.forget_edges()
    assert not env.maps.known_edges.known.any()


def observation_batch(env: SingleAgentMonitoringEnv, steps: int = 12, seed: int = 0) -> dict[str, th.Tensor]:
    obs, _ = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    collected = [obs]
    for _ in range(steps - 1):
        obs, *_ = env.step(int(rng.choice(np.flatnonzero(env.action_masks()))))
        collected.append(obs)
    return {key: th.as_tensor(np.stack([np.asarray(o[key]) for o in collected])) for key in collected[0]}


@pytest.mark.parametrize(
    "graph,settings",
    [
        ("paper-50", {}),  # the default policy: dense kernel, Laplacian rows
        (SPARSE, {"laplacian": "none"}),  # sparse kernel on the edge list itself
        (SPARSE, {"laplacian": "none", "gat_backend": "sparse"}),
        (SPARSE, {}),  # sparse kernel with the Laplacian encoding
        (SPARSE, {"neglect_bound": 30.0, "laplacian": "none"}),  # rule 8's search on the known graph
    ],
    ids=["paper50-default", "sparse", "sparse-backend", "sparse-laplacian", "neglect-bound"],
)
@pytest.mark.parametrize("stored", [False, True], ids=["collected", "from-buffer"])
def test_the_policy_computes_the_same_on_both_layouts(graph, settings, stored) -> None:
    dense_env = SingleAgentMonitoringEnv(graph, n_agents=2, max_cycles=20)
    edge_env = SingleAgentMonitoringEnv(graph, n_agents=2, max_cycles=20, layout="edges")
    dense_obs, edge_obs = observation_batch(dense_env), observation_batch(edge_env)
    if stored:  # a rollout buffer hands every entry back as float32
        edge_obs = {key: value.float() for key, value in edge_obs.items()}
    policies = []
    for env in (dense_env, edge_env):
        th.manual_seed(0)
        policy = DCBFActorCriticPolicy(env.observation_space, env.action_space, lambda _: 3e-4, **settings)
        policy.set_training_mode(False)
        policies.append(policy)
    dense_policy, edge_policy = policies
    with th.no_grad():
        for name, run in (
            ("features", lambda p, o: p.features_extractor(p._preprocess(o))),
            ("values", lambda p, o: p.predict_values(o)),
            ("logits", lambda p, o: p.get_distribution(o).distribution.logits),
            ("masks", lambda p, o: p.compute_masks(o)),
        ):
            th.testing.assert_close(run(edge_policy, edge_obs), run(dense_policy, dense_obs), msg=name)
    actions = th.as_tensor([0] * 12)
    values, log_prob, entropy = edge_policy.evaluate_actions(edge_obs, actions)  # with gradients
    expected = dense_policy.evaluate_actions(dense_obs, actions)
    for got, want in zip((values, log_prob, entropy), expected):
        th.testing.assert_close(got, want)


def test_batched_edges_match_the_dense_edge_list() -> None:
    from sb3_pm.policies.attention import batched_edge_index

    env = SingleAgentMonitoringEnv(SPARSE, n_agents=2, max_cycles=20, layout="edges")
    obs = observation_batch(env)
    adjacency = edges_to_adjacency(obs["edge_index"], obs["edge_mask"], SPARSE.n_nodes)
    edges = batched_edges(obs["edge_index"], obs["edge_mask"], SPARSE.n_nodes)
    assert th.equal(edges, batched_edge_index(adjacency))


EDGES = functools.partial(persistent_monitoring_v0.parallel_env, illegal_action="stay", layout="edges")


def test_pettingzoo_api_tests_pass_in_the_edges_layout() -> None:
    aec = persistent_monitoring_v0.env(illegal_action="stay", layout="edges", max_cycles=60)
    api_test(aec, num_cycles=60)
    parallel_api_test(EDGES(max_cycles=60), num_cycles=60)
    parallel_api_test(EDGES(max_cycles=40, graph=SMALL, failures={"agent_1": 10}), num_cycles=40)


def test_a_team_trains_on_the_edges_layout() -> None:
    policy_kwargs = {"laplacian": "none", "hidden_dim": 16, "gat_heads": 2}
    hyperparams = {"n_steps": 16, "batch_size": 32, "n_epochs": 2, "learning_rate": "lin_1e-3",
                   "policy_kwargs": policy_kwargs}
    team = IndependentPPO(
        SPARSE,
        n_agents=2,
        env_kwargs={"max_cycles": 20, "layout": "edges"},
        n_envs=2,
        seed=0,
        hyperparams=hyperparams,
    )
    before = [p.detach().clone() for a in team.agents for p in team.models[a].policy.parameters()]
    team.learn(256)
    assert team.num_timesteps == 256
    buffer = team.models[team.agents[0]].rollout_buffer
    assert "edge_mask" in buffer.observations and "adjacency" not in buffer.observations
    after = [p.detach() for a in team.agents for p in team.models[a].policy.parameters()]
    assert any(not th.equal(a, b) for a, b in zip(before, after))
    env = persistent_monitoring_v0.parallel_env(graph=SPARSE, n_agents=2, max_cycles=20, layout="edges")
    observations, _ = env.reset(seed=1)
    team.reset(env, seed=1)
    for _ in range(5):  # the trained team acts on edges-layout observations (one pass per learner)
        actions = team.predict_dict(observations, deterministic=True)
        assert all(observations[a]["action_mask"][node] == 1 for a, node in actions.items())
        observations, *_ = env.step(actions)


@pytest.mark.parametrize(
    "settings,message",
    [
        ({"layout": "sparse"}, "layout must be one of ('dense', 'edges'), got 'sparse'"),
        ({"layout": None}, "layout must be one of ('dense', 'edges'), got None"),
        ({"layout": "edges", "observation": "local"}, "needs observation='map'"),
        ({"layout": "edges", "graph": "family:er"}, "not a graph family"),
    ],
)
def test_bad_layouts_are_one_line_errors(settings, message) -> None:
    with pytest.raises(InputError) as error:
        persistent_monitoring_v0.parallel_env(**settings)
    assert message in str(error.value) and "\n" not in str(error.value)


def test_the_config_schema_takes_the_layout() -> None:
    from sb3_pm.zoo.schema import ENV

    key = next(k for k in ENV.keys if k.name == "layout")
    assert key.default == "dense" and key.choices == ("dense", "edges")


def test_sb3_pm_train_takes_the_edges_layout_from_a_config(tiny_train) -> None:
    """The normal training entry: a YAML config's ``env_kwargs: {layout: edges}``, the DCBF policy."""
    import yaml

    from sb3_pm.cli import main

    config, graph, out = tiny_train
    lines = [line for line in config.read_text().splitlines() if "algo:" not in line]  # the DCBF default
    config.write_text("\n".join(lines).replace("{max_cycles: 10}", "{max_cycles: 10, layout: edges}"))
    argv = ["train", "--config", str(config), "--env", str(graph), "--timesteps", "200", "--out", str(out)]
    assert main([*argv, "--no-progress"]) == 0
    resolved = yaml.safe_load((out / "config.yml").read_text())
    assert resolved["env_kwargs"]["layout"] == "edges"


def test_the_memory_estimate_counts_edges_not_pairs() -> None:
    from sb3_pm.zoo.memory import training_estimate

    n, edges = 20_000, 60_000
    dense = dict(training_estimate(n, 250, n_envs=1, n_steps=512, batch_size=64, dense_attention=False).parts)
    sparse = dict(
        training_estimate(
            n, 250, n_envs=1, n_steps=512, batch_size=64, dense_attention=False, edges=edges, laplacian=False
        ).parts
    )
    assert sparse["rollout buffers"] == 250 * 512 * (12 * edges + n * (4 * 7 + 1))
    assert sparse["env copies"] == edges * 2 * 250 and sparse["largest minibatch"] == 0
    assert sparse["graph"] == n * n  # the GraphSpec's own (N, N) bool adjacency stays
    assert sum(sparse.values()) < sum(dense.values()) / 100


def test_local_greedy_acts_alike_on_both_layouts() -> None:
    from sb3_pm.baselines.local_greedy import LocalGreedyTeam

    moves = []
    for layout in ("dense", "edges"):
        env = persistent_monitoring_v0.parallel_env(graph=SMALL, n_agents=3, max_cycles=30, layout=layout)
        team = LocalGreedyTeam()
        observations, _ = env.reset(seed=2)
        team.reset(env, seed=2)
        chosen = []
        while env.agents:
            actions = team.predict_dict(observations)
            chosen.append(actions)
            observations, *_ = env.step(actions)
        moves.append(chosen)
    assert moves[0] == moves[1]


def test_the_flat_views_adjacency_needs_the_dense_layout() -> None:
    from sb3_pm.integrations.flat_env import Flattener

    env = persistent_monitoring_v0.parallel_env(graph=SMALL, layout="edges")
    Flattener(env.observation_space("agent_0"), adjacency=False)  # no adjacency entries: fine
    with pytest.raises(InputError, match="layout='dense'"):
        Flattener(env.observation_space("agent_0"), adjacency=True)
