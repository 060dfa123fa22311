"""Deploying ``pretrained:transfer_split`` on large sites in the env's edges layout.

What a large site computes without the all-pairs tables must be what the small sites compute with
them: per-target routes (:mod:`sb3_pm.graphs.routes`) against ``GraphSpec``'s ``hop_distances``
and ``next_hop``, the territory split, rule and advice on either, the neglect bound's search over
edge lists against its dense search, and the actor's logits from the allowed nodes'
neighbourhoods (:mod:`sb3_pm.policies.local_pass`) against the full pass. Then short episodes of
the transfer team on a 1,000-node site and on the 5,000-node city with 64 agents, each in a process
of its own, with its peak memory: ``pretrained:transfer_split``, which needs no plan, and (marked
slow) the shipped ``pretrained:transfer`` on the plan's tours.
"""

from __future__ import annotations

import json
import textwrap

import numpy as np
import pytest
import torch as th

from sb3_pm.baselines import make_team
from sb3_pm.envs import persistent_monitoring_v0
from sb3_pm.graphs import GraphSpec, resolve_graph
from sb3_pm.graphs import routes as routes_module
from sb3_pm.graphs.large_sites import city_streets
from sb3_pm.graphs.routes import DenseRoutes, TargetRoutes
from sb3_pm.graphs.territories import site_territories, target_territories
from sb3_pm.policies.edges import edges_to_adjacency
from sb3_pm.policies.neglect_bound import edge_hop_distances, hop_distances
from tests.conftest import child_result, episode_moves

GRAPHS = {
    "paper-50": lambda: resolve_graph("paper-50"),
    "rooms-4": lambda: resolve_graph("rooms-4"),
    "city-300": lambda: city_streets(300, seed=3),
}


def fresh(name: str) -> GraphSpec:
    """A new spec of the graph (its cached routes are its own: presets are shared instances)."""
    graph = GRAPHS[name]()
    return GraphSpec(graph.adjacency, graph.targets, name=graph.name, positions=graph.positions)


@pytest.fixture
def sparse_routes(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every graph built from here on takes the per-target routes, whatever its size."""
    monkeypatch.setattr(routes_module, "DENSE_ROUTES_MAX", 0)


@pytest.mark.parametrize("name", GRAPHS)
def test_target_routes_equal_the_all_pairs_tables(name: str) -> None:
    graph = fresh(name)
    dense = DenseRoutes(graph.hop_distances, graph.next_hop, graph.target_indices)
    sparse = TargetRoutes(graph)
    targets = graph.target_indices
    for node in range(graph.n_nodes):
        assert np.array_equal(sparse.distances(node, targets), dense.distances(node, targets))
        for goal in targets:
            assert sparse.next_hop(node, int(goal)) == dense.next_hop(node, int(goal)), (node, goal)
    assert np.array_equal(sparse.between_targets(), dense.between_targets())


def test_target_routes_refuse_a_node_that_is_not_a_target() -> None:
    graph = fresh("paper-50")
    plain = int(np.flatnonzero(~graph.targets)[0])
    with pytest.raises(ValueError, match="targets only"):
        TargetRoutes(graph).next_hop(0 if plain else 1, plain)


@pytest.mark.parametrize("name", GRAPHS)
@pytest.mark.parametrize("n_agents", [2, 4, 7])
def test_the_split_from_target_routes_is_the_dense_split(
    name: str, n_agents: int, sparse_routes: None
) -> None:
    graph = fresh(name)
    assert isinstance(graph.routes, TargetRoutes)
    dense = target_territories(graph.hop_distances, graph.target_indices, n_agents)
    assert np.array_equal(site_territories(graph, n_agents), dense)


@pytest.mark.parametrize("name", GRAPHS)
def test_the_lower_bounds_from_target_routes_equal_the_dense_ones(
    name: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    from sb3_pm.planning.bound import priced_bound, stepwise_bound

    starts = np.array([0, 3, 7])
    dense = fresh(name)
    expected = stepwise_bound(dense, starts, 60, 100), priced_bound(dense, starts, 60, 100)
    monkeypatch.setattr(routes_module, "DENSE_ROUTES_MAX", 0)
    graph = fresh(name)
    assert np.array_equal(stepwise_bound(graph, starts, 60, 100), expected[0])
    assert priced_bound(graph, starts, 60, 100) == expected[1]
    assert "hop_distances" not in graph.__dict__


def _moves(graph: GraphSpec, policy: str, steps: int = 60) -> list[dict[str, int]]:
    team = make_team(policy)
    env = persistent_monitoring_v0.parallel_env(graph=graph, n_agents=4, max_cycles=steps)
    return episode_moves(env, team, seed=5)


@pytest.mark.parametrize("name", GRAPHS)
@pytest.mark.parametrize("policy", ["territory_patrol", "grazing", "sit_on_nodes", "tour_patrol"])
def test_baselines_move_alike_on_either_routes(name: str, policy: str, monkeypatch) -> None:
    dense_graph = fresh(name)
    expected = _moves(dense_graph, policy)
    assert isinstance(dense_graph.routes, DenseRoutes)
    monkeypatch.setattr(routes_module, "DENSE_ROUTES_MAX", 0)
    sparse_graph = fresh(name)
    assert _moves(sparse_graph, policy) == expected
    assert isinstance(sparse_graph.routes, TargetRoutes)
    assert "next_hop" not in sparse_graph.__dict__  # no all-pairs table was built


def _advice_columns(graph: GraphSpec, layout: str, steps: int = 40) -> list[np.ndarray]:
    env = persistent_monitoring_v0.parallel_env(
        graph=graph,
        n_agents=3,
        max_cycles=steps,
        advice_input=True,
        territory_input=True,
        graph_knowledge="known",
        target_knowledge="known",
        layout=layout,
    )
    observations, _ = env.reset(seed=2)
    rng = np.random.default_rng(2)
    columns = []
    while env.agents:
        columns.append(np.stack([observations[a]["nodes"][:, -2:] for a in env.agents]))
        actions = {
            a: int(rng.choice(np.flatnonzero(observations[a]["action_mask"]))) for a in env.agents
        }
        observations, *_ = env.step(actions)
    return columns


@pytest.mark.parametrize("name", GRAPHS)
def test_advice_and_territory_columns_alike_on_either_routes(
    name: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    expected = _advice_columns(fresh(name), "dense")
    monkeypatch.setattr(routes_module, "DENSE_ROUTES_MAX", 0)
    graph = fresh(name)
    got = _advice_columns(graph, "edges")
    assert all(np.array_equal(a, b) for a, b in zip(got, expected)) and len(got) == len(expected)
    assert "hop_distances" not in graph.__dict__


def test_edge_searches_equal_the_dense_search() -> None:
    graph = fresh("city-300")
    rows_i, rows_j = np.nonzero(graph.adjacency)
    edge_index = th.as_tensor(np.stack((rows_i, rows_j)))[None].expand(6, 2, -1).clone()
    generator = th.Generator().manual_seed(0)
    mask = (th.rand((6, rows_i.size), generator=generator) < 0.8).to(th.int8)
    mask[:3] = mask[0]  # maps with the same known edges share one search
    sources = th.randint(0, graph.n_nodes, (6,), generator=generator)
    rows = th.arange(6)
    dense = hop_distances(edges_to_adjacency(edge_index, mask, graph.n_nodes), sources)
    assert th.equal(edge_hop_distances((edge_index, mask), rows, sources, graph.n_nodes), dense)
    picked = th.tensor([4, 1])
    some = edge_hop_distances((edge_index, mask), picked, sources[picked], graph.n_nodes)
    assert th.equal(some, dense[picked])


@pytest.fixture(scope="module")
def transfer_on_small_city() -> tuple[object, GraphSpec]:
    from sb3_pm.evaluation import resolve_team

    graph = city_streets(300, seed=3)
    team = resolve_team("pretrained:transfer_split", graph=graph, layout="edges")
    team.set_filter(neglect_bound=None)  # no calibration here: the bound is compared on its own
    return team, graph


@pytest.mark.parametrize("deterministic", [True, False])
def test_one_pass_per_learner_acts_as_one_pass_per_agent(transfer_on_small_city, deterministic: bool) -> None:
    from sb3_pm.agents.deployment.rule import _policy_actions

    team, graph = transfer_on_small_city
    env = team.make_env(graph, n_agents=9, max_cycles=30)  # 9 agents on 4 learners
    observations, _ = env.reset(seed=3)
    team.reset(env, seed=3)
    for step in range(30):
        th.manual_seed(step)
        together = team.predict_dict(observations, deterministic=deterministic)
        th.manual_seed(step)
        alone = {
            a: _policy_actions(team.policy_for(a), [observations[a]], deterministic)[0] for a in env.agents
        }
        assert together == alone, step
        observations, *_ = env.step(together)


def test_the_neglect_bound_forces_alike_on_both_layouts(transfer_on_small_city) -> None:
    from sb3_pm.policies.dcbf import DCBFConfig, dcbf_filter_from_map

    team, graph = transfer_on_small_city
    env = team.make_env(graph, n_agents=4, max_cycles=80)  # the edges layout: the team's now
    observations, _ = env.reset(seed=1)
    team.reset(env, seed=1)
    for _ in range(60):  # long enough for targets to fall due under a tight bound
        observations, *_ = env.step(team.predict_dict(observations))
    keys = observations["agent_0"]
    batch = {k: th.as_tensor(np.stack([observations[a][k] for a in env.agents])) for k in keys}
    pre = team.policy_for("agent_0")._preprocess(batch)
    dense = {k: v for k, v in pre.items() if k not in ("edge_index", "edge_mask")}
    dense["adjacency"] = edges_to_adjacency(pre["edge_index"], pre["edge_mask"], graph.n_nodes)
    config = DCBFConfig(neglect_bound=8.0, neglect_scope="known", barrier=False, freeze_steps=0)
    u_hat = pre["nodes"][..., 0]
    mask_e, forced_e = dcbf_filter_from_map(pre, u_hat, config, 100.0)
    mask_d, forced_d = dcbf_filter_from_map(dense, u_hat, config, 100.0)
    assert th.equal(mask_e, mask_d) and th.equal(forced_e, forced_d)
    assert bool(forced_e.any())  # the bound did bind, so the searches were compared


def test_allowed_logits_equal_the_full_pass(transfer_on_small_city) -> None:
    from sb3_pm.policies.heads import masked_mode
    from sb3_pm.policies.local_pass import allowed_logits

    team, graph = transfer_on_small_city
    env = team.make_env(graph, n_agents=6, max_cycles=30)
    observations, _ = env.reset(seed=4)
    team.reset(env, seed=4)
    policy = team.policy_for("agent_0")
    compared = 0
    with th.no_grad():
        for _ in range(25):
            batch = {k: np.stack([observations[a][k] for a in env.agents]) for k in observations["agent_0"]}
            pre = policy._preprocess(policy.obs_to_tensor(batch)[0])
            u_hat = policy.uncertainty(pre)
            masks = policy._masks(pre, u_hat, batch["action_mask"].astype(bool))
            full = policy._logits(pre, u_hat, masks)
            local = allowed_logits(policy, pre, u_hat, masks)
            assert th.allclose(local[masks], full[masks], rtol=1e-5, atol=1e-5)
            assert th.equal(masked_mode(local, masks), masked_mode(full, masks))
            compared += int(masks.sum())
            observations, *_ = env.step(team.predict_dict(observations))
    assert compared > 100


def test_the_shared_edge_list_finds_the_edges_a_full_scan_finds(transfer_on_small_city) -> None:
    from sb3_pm.policies.local_pass import _all_edges, _shared_edges

    team, graph = transfer_on_small_city
    env = persistent_monitoring_v0.parallel_env(graph=graph, n_agents=5, max_cycles=10, layout="edges")
    observations, _ = env.reset(seed=0)  # discovered edges: each map knows a few
    for _ in range(8):
        last = {a: int(np.flatnonzero(observations[a]["action_mask"])[-1]) for a in env.agents}
        observations, *_ = env.step(last)
    keys = observations["agent_0"]
    pre = {k: th.as_tensor(np.stack([observations[a][k] for a in env.agents])) for k in keys}
    pre["nodes"] = pre["nodes"].float()
    nodes = th.unique(th.randint(0, 5 * graph.n_nodes, (400,), generator=th.Generator().manual_seed(1)))
    shared, scanned = _shared_edges(pre)(nodes), _all_edges(pre, graph.n_nodes)(nodes)
    assert scanned[0].numel() > 0
    assert th.equal(shared[0], scanned[0]) and th.equal(shared[1], scanned[1])


EPISODE = textwrap.dedent(
    """
    import json, resource, sys
    import numpy as np, torch
    torch.set_num_threads(1)
    from sb3_pm.evaluation import resolve_team
    from sb3_pm.graphs.large_sites import city_streets
    graph = city_streets(1000, seed=1)
    team = resolve_team("pretrained:transfer_split", graph=graph, layout="edges")
    team.set_filter(neglect_bound=60.0, neglect_scope="territory")
    env = team.make_env(graph, n_agents=12, max_cycles=20)
    observations, _ = env.reset(seed=0)
    team.reset(env, seed=0)
    legal = steps = 0
    while env.agents:
        actions = team.predict_dict(observations)
        legal += sum(bool(observations[a]["action_mask"][actions[a]]) for a in actions)
        steps += len(actions)
        observations, *_ = env.step(actions)
    adjacency_built = "hop_distances" in graph.__dict__ or "next_hop" in graph.__dict__
    # VmHWM is this process image's own peak; ru_maxrss keeps the forking parent's (Linux keeps
    # it across exec), which under pytest is the whole test session's
    status = open("/proc/self/status").read().split("VmHWM:")
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    peak_kb = int(status[1].split()[0]) if len(status) > 1 else own
    print(json.dumps({"legal": legal, "moves": steps, "all_pairs": adjacency_built,
                      "peak_mb": peak_kb / 1024}))
    """
)


def test_a_transfer_episode_on_a_1000_node_site_in_the_edges_layout() -> None:
    result = child_result(EPISODE, timeout=600)
    assert result["moves"] == 12 * 20 and result["legal"] == result["moves"]
    assert not result["all_pairs"]  # 1,000 nodes: above DENSE_ROUTES_MAX, per-target routes
    assert result["peak_mb"] < 1500, result  # measured 480 MB (importing torch alone: about 300)


SITE_5K = textwrap.dedent(
    """
    import json, time
    import torch
    torch.set_num_threads(1)
    start = time.perf_counter()
    from sb3_pm.evaluation import resolve_team
    from sb3_pm.graphs import resolve_graph
    graph = resolve_graph("city-5k")
    team = resolve_team("pretrained:transfer_split", graph=graph, layout="edges")
    team.set_filter(neglect_bound=None)  # as the zero-shot records run it (--neglect-bound off)
    env = team.make_env(graph, n_agents=64, max_cycles=10)
    observations, _ = env.reset(seed=0)
    team.reset(env, seed=0)
    legal = moves = 0
    while env.agents:
        actions = team.predict_dict(observations)
        legal += sum(bool(observations[a]["action_mask"][actions[a]]) for a in actions)
        moves += len(actions)
        observations, *_ = env.step(actions)
    status = open("/proc/self/status").read()  # VmHWM: this image's own peak (see EPISODE)
    print(json.dumps({"legal": legal, "moves": moves, "seconds": time.perf_counter() - start,
                      "all_pairs": "hop_distances" in graph.__dict__ or "next_hop" in graph.__dict__,
                      "peak_mb": int(status.split("VmHWM:")[1].split()[0]) / 1024}))
    """
)


def test_a_transfer_episode_on_the_5000_node_city_with_64_agents_fits_in_2_gb() -> None:
    """The zero-shot records' setting (docs/RESULTS.md, "Sites of thousands of nodes"), 10 steps;
    measured 590 MB and 6 s in the child (9 s in all) on a busy 2-core machine."""
    result = child_result(SITE_5K, timeout=900)
    assert result["moves"] == 64 * 10 and result["legal"] == result["moves"]
    assert not result["all_pairs"]
    assert result["peak_mb"] < 2048, result


@pytest.mark.slow
def test_the_shipped_transfer_team_on_the_5000_node_city_on_planned_tours_fits_in_2_gb() -> None:
    """``pretrained:transfer`` as deployed there (``--territories planned_tours``): the plan for
    the episode's starts, then 10 steps, in a process of its own."""
    script = SITE_5K.replace('"pretrained:transfer_split"', '"pretrained:transfer"').replace(
        "n_agents=64, max_cycles=10)", "n_agents=64, max_cycles=10, territories='planned_tours')"
    )
    assert "territories='planned_tours'" in script and '"pretrained:transfer"' in script
    result = child_result(script, timeout=1200)
    assert result["moves"] == 64 * 10 and result["legal"] == result["moves"]
    assert not result["all_pairs"]
    assert result["peak_mb"] < 2048, result


def test_sb3_pm_evaluate_takes_the_layout(capsys, tmp_path) -> None:
    from sb3_pm.cli import main

    out = tmp_path / "run.json"
    argv = ["evaluate", "--policy", "pretrained:transfer_split", "--graph", "city-1k", "--agents", "12"]
    argv += ["--layout", "edges", "--steps", "5", "--episodes", "1", "--neglect-bound", "off"]
    assert main([*argv, "--json", str(out), "--no-progress"]) == 0
    assert json.loads(out.read_text())["mean"]["steps"] == 5
    code = main(["evaluate", "--policy", "territory_patrol", "--graph", "rooms-4", "--layout", "edges",
                 "--steps", "5", "--episodes", "1", "--no-progress"])
    assert code == 0
    with pytest.raises(SystemExit):
        main(["evaluate", "--policy", "random", "--layout", "sparse"])
    assert "invalid choice: 'sparse'" in capsys.readouterr().err


def test_the_memory_estimate_of_an_edges_layout_evaluation_counts_edges() -> None:
    from sb3_pm.zoo.memory import evaluation_estimate

    dense = evaluation_estimate(5000, 64, True, dense_attention=False).total
    edges = evaluation_estimate(5000, 64, True, dense_attention=False, edges=37_000).total
    assert edges < dense / 20 and edges < 2 * 1024**3


def test_a_team_on_its_own_graph_is_rebuilt_for_another_layout_and_acts_alike() -> None:
    from sb3_pm.evaluation import resolve_team

    graph = resolve_graph("paper-50")
    dense = resolve_team("pretrained:paper-50", graph=graph)
    edges = resolve_team("pretrained:paper-50", graph=graph, layout="edges")
    assert edges is not dense and edges.env_settings()["layout"] == "edges"
    assert resolve_team("pretrained:paper-50", graph=graph, layout="dense").env_settings().get(
        "layout", "dense"
    ) == "dense"
    envs = [team.make_env(graph, max_cycles=40) for team in (dense, edges)]
    observations = [env.reset(seed=6)[0] for env in envs]
    for team, env in zip((dense, edges), envs):
        team.reset(env, seed=6)
    assert "edge_index" in observations[1]["agent_0"] and "adjacency" in observations[0]["agent_0"]
    teams = (dense, edges)
    for _ in range(40):
        actions = [team.predict_dict(obs, deterministic=True) for team, obs in zip(teams, observations)]
        assert actions[0] == actions[1]
        observations = [env.step(action)[0] for env, action in zip(envs, actions)]
