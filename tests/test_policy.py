"""GAT extractor, state estimator and the DCBF policy's structure."""

from __future__ import annotations

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.preprocessing import preprocess_obs

from sb3_pm.envs.single_agent import SingleAgentMonitoringEnv
from sb3_pm.graphs import erdos_renyi
from sb3_pm.policies import (
    DCBFActorCriticPolicy,
    GATFeaturesExtractor,
    GraphAttention,
    StateEstimator,
)
from sb3_pm.policies.estimator import transition_pairs

N = 12


@pytest.fixture(scope="module")
def env() -> SingleAgentMonitoringEnv:
    return SingleAgentMonitoringEnv(
        erdos_renyi(N, 0.3, n_targets=3, seed=1), n_agents=2, max_cycles=20, graph_knowledge="known"
    )


def observation_batch(env: SingleAgentMonitoringEnv, steps: int = 8, seed: int = 0) -> dict[str, th.Tensor]:
    """A batch of raw observations from a random walk, as SB3 tensors."""
    obs, _ = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    collected = [obs]
    for _ in range(steps - 1):
        obs, *_ = env.step(int(rng.choice(np.flatnonzero(env.action_masks()))))
        collected.append(obs)
    return {key: th.as_tensor(np.stack([np.asarray(o[key]) for o in collected])) for key in collected[0]}


def make_policy(env: SingleAgentMonitoringEnv, **kwargs: object) -> DCBFActorCriticPolicy:
    return DCBFActorCriticPolicy(env.observation_space, env.action_space, lambda _: 3e-4, **kwargs)  # type: ignore[arg-type]


def random_graphs(batch: int, n: int, density: float, seed: int = 0) -> th.Tensor:
    generator = th.Generator().manual_seed(seed)
    upper = th.triu((th.rand(batch, n, n, generator=generator) < density).float(), diagonal=1)
    return upper + upper.transpose(1, 2)


class TestLayers:
    @pytest.mark.parametrize("density", [0.02, 0.3])
    def test_gat_dense_and_sparse_agree(self, density: float) -> None:
        th.manual_seed(0)
        layer = GraphAttention(7, 8, heads=3)
        x, adjacency = th.randn(4, 20, 7), random_graphs(4, 20, density)
        dense, sparse = layer(x, adjacency, dense=True), layer(x, adjacency, dense=False)
        assert dense.shape == (4, 20, 8)
        th.testing.assert_close(dense, sparse, atol=1e-5, rtol=1e-5)

    def test_empty_graph(self) -> None:
        layer = GraphAttention(4, 4, heads=2)
        x = th.randn(2, 5, 4)
        empty = th.zeros(2, 5, 5)
        th.testing.assert_close(
            layer(x, empty, dense=True), layer(x, empty, dense=False), atol=1e-5, rtol=1e-5
        )

    def test_auto_backend_follows_density(self) -> None:
        from sb3_pm.policies.attention import use_dense as _use_dense

        assert _use_dense(random_graphs(16, 80, 0.2), "auto")
        assert not _use_dense(random_graphs(16, 80, 0.01), "auto")
        assert _use_dense(random_graphs(16, 60, 0.01), "auto")  # small graphs: always dense
        assert _use_dense(random_graphs(16, 60, 0.01), "dense")
        assert not _use_dense(random_graphs(16, 60, 0.2), "sparse")
        # A rollout step's few maps always run dense under "auto" (faster whatever the density).
        assert _use_dense(random_graphs(2, 60, 0.01), "auto")
        assert not _use_dense(random_graphs(2, 60, 0.2), "sparse")

    @pytest.mark.parametrize("chunk", [1, 3, 64])
    def test_chunked_attention_matches_autograd(self, chunk: int) -> None:
        """The fused kernel's values and gradients equal plain autograd's over the unfused maths."""
        from sb3_pm.policies.attention import _ChunkedAttention, attention_bias, unique_graphs

        th.manual_seed(0)
        batch, heads, n, c = 10, 3, 9, 4
        adjacency = random_graphs(batch, n, 0.3)
        adjacency[5:] = adjacency[0]  # repeated graphs: exercised through the distinct-graph index
        graphs, index = unique_graphs(adjacency)
        assert len(graphs) == 5 and th.equal(graphs[index], adjacency)
        a_dst, a_src = (
            th.randn(batch, heads, n, requires_grad=True),
            th.randn(batch, heads, n, requires_grad=True),
        )
        h = th.randn(batch, heads, n, c, requires_grad=True)
        scores = th.nn.functional.leaky_relu(a_dst.unsqueeze(-1) + a_src.unsqueeze(-2), 0.2)
        expected = th.matmul(th.softmax(scores + attention_bias(adjacency), -1), h)
        fused = _ChunkedAttention.apply(a_dst, a_src, h, attention_bias(graphs), index, 0.2, chunk)
        th.testing.assert_close(fused, expected)
        weight = th.randn_like(expected)
        grads = th.autograd.grad((expected * weight).sum(), (a_dst, a_src, h))
        fused_grads = th.autograd.grad((fused * weight).sum(), (a_dst, a_src, h))
        for got, want in zip(fused_grads, grads):
            th.testing.assert_close(got, want, atol=1e-5, rtol=1e-5)

    def test_unique_graphs_with_equal_edge_counts(self) -> None:
        from sb3_pm.policies.attention import unique_graphs

        adjacency = th.zeros(12, 4, 4)
        adjacency[:6, 0, 1] = adjacency[:6, 1, 0] = 1.0
        adjacency[6:, 2, 3] = adjacency[6:, 3, 2] = 1.0  # same edge count, different graph
        graphs, index = unique_graphs(adjacency)
        assert len(graphs) == 2 and th.equal(graphs[index], adjacency)

    def test_unique_graphs_of_one_map(self) -> None:
        """A batch of one repeated map (a known topology) gives that map once; one differing entry
        anywhere in the batch gives two."""
        from sb3_pm.policies.attention import unique_graphs

        adjacency = random_graphs(1, 7, 0.4).expand(12, 7, 7).contiguous()
        graphs, index = unique_graphs(adjacency)
        assert graphs.shape == (1, 7, 7) and th.equal(index, th.zeros(12, dtype=th.long))
        assert th.equal(graphs[index], adjacency)
        adjacency[11, 6, 5] = 1.0 - adjacency[11, 6, 5]
        graphs, index = unique_graphs(adjacency)
        assert len(graphs) == 2 and th.equal(graphs[index], adjacency)

    @pytest.mark.parametrize("collide", [False, True])
    def test_unique_graphs_keep_the_earlier_order(
        self, collide: bool, monkeypatch: pytest.MonkeyPatch
    ) -> None:
        """Distinct graphs come out in the order of the earlier search (by edge count, lexicographic
        where counts tie), which keeps trained parameters bit for bit; a key collision is caught by
        the exact comparison and changes nothing."""
        from sb3_pm.policies import attention

        def earlier(adjacency: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
            flat = adjacency.reshape(adjacency.shape[0], -1)
            counts = flat.sum(-1)
            if len(th.unique(counts)) == len(th.unique(flat, dim=0)):
                _, inverse = th.unique(counts, return_inverse=True)
            else:
                _, inverse = th.unique(flat, dim=0, return_inverse=True)
            first = th.full((int(inverse.max()) + 1,), len(flat), dtype=th.long)
            first.scatter_reduce_(0, inverse, th.arange(len(flat)), reduce="amin")
            return adjacency[first], inverse

        if collide:
            monkeypatch.setattr(
                attention, "_graph_keys", lambda flat: th.zeros(flat.shape[0], dtype=th.float64)
            )
        # Counts that differ, in the opposite of lexicographic order: A has one edge (0, 1), B two
        # edges (3, 1) and (3, 2); sorted rows put B first, edge counts put A first.
        distinct_counts = th.zeros(10, 4, 4)
        distinct_counts[::2, 0, 1] = distinct_counts[::2, 1, 0] = 1.0
        distinct_counts[1::2, 3, 1] = distinct_counts[1::2, 1, 3] = 1.0
        distinct_counts[1::2, 3, 2] = distinct_counts[1::2, 2, 3] = 1.0
        tied_counts = random_graphs(14, 6, 0.4, seed=1)
        tied_counts[:2] = 0.0  # two distinct graphs with one edge each
        tied_counts[0, 0, 1] = tied_counts[0, 1, 0] = tied_counts[1, 2, 3] = tied_counts[1, 3, 2] = 1.0
        for adjacency in (distinct_counts, tied_counts, random_graphs(14, 6, 0.4, seed=2)):
            graphs, index = attention.unique_graphs(adjacency)
            want_graphs, want_index = earlier(adjacency)
            assert th.equal(graphs, want_graphs) and th.equal(index, want_index)

    def test_encoding_per_graph_matches_concatenated_input(self) -> None:
        """The first layer's per-distinct-graph product with the encoding equals the plain layer."""
        from sb3_pm.policies.attention import unique_graphs
        from sb3_pm.policies.encodings import laplacian_rows

        th.manual_seed(0)
        layer = GraphAttention(5 + 11, 8, heads=2)
        adjacency = random_graphs(12, 11, 0.3)
        adjacency[4:] = adjacency[1]
        x = th.randn(12, 11, 5)
        graphs, index = unique_graphs(adjacency)
        full = th.cat((x, laplacian_rows(adjacency)), -1)
        for dense in (True, False):
            th.testing.assert_close(
                layer(x, adjacency, dense=dense, encoding=(laplacian_rows(graphs), index)),
                layer(full, adjacency, dense=dense),
                atol=1e-5,
                rtol=1e-5,
            )

    def test_bad_options(self, env: SingleAgentMonitoringEnv) -> None:
        with pytest.raises(ValueError, match="laplacian"):
            GATFeaturesExtractor(env.observation_space, laplacian="full")
        with pytest.raises(ValueError, match="backend"):
            GraphAttention(3, 3, backend="gpu")


class TestExtractor:
    @pytest.mark.parametrize("laplacian", ["rows", "none"])
    def test_shapes(self, env: SingleAgentMonitoringEnv, laplacian: str) -> None:
        extractor = GATFeaturesExtractor(env.observation_space, hidden_dim=16, laplacian=laplacian)
        pre = preprocess_obs(observation_batch(env), env.observation_space)
        out = extractor(pre)
        assert out.shape == (8, N * 16) and extractor.features_dim == N * 16
        assert extractor.node_embeddings(pre).shape == (8, N, 16)
        assert th.isfinite(out).all()

    def test_collection_cache_follows_the_adjacency(self, env: SingleAgentMonitoringEnv) -> None:
        """Gradient-free small batches reuse the last graph inputs only while the adjacency is unchanged."""
        extractor = GATFeaturesExtractor(env.observation_space, hidden_dim=8)
        pre = preprocess_obs(observation_batch(env, steps=4), env.observation_space)
        changed = {**pre, "adjacency": random_graphs(4, N, 0.3, seed=3)}
        for batch in (pre, changed, pre):
            expected = extractor.node_embeddings(batch)  # gradients on: never cached
            with th.no_grad():
                th.testing.assert_close(extractor.node_embeddings(batch), expected)

    def test_node_features_are_normalized(self, env: SingleAgentMonitoringEnv) -> None:
        extractor = GATFeaturesExtractor(env.observation_space, laplacian="none")
        pre = preprocess_obs(observation_batch(env, steps=20), env.observation_space)
        x = extractor.node_inputs(pre)
        assert x.min() >= 0.0 and x.max() <= 1.0


class TestEstimator:
    def test_predicts_zero_off_targets_and_in_range(self) -> None:
        inv_high = th.ones(4, 5) / th.tensor([100.0, 20.0, 1.0, 1.0, 1.0])
        estimator = StateEstimator(5, 100.0, inv_high)
        nodes = th.rand(3, 4, 5) * th.tensor([100.0, 20.0, 0.0, 1.0, 1.0])  # no target known
        assert (estimator(nodes) == 0).all()
        nodes[..., 2] = 1.0
        u_hat = estimator(nodes)
        assert ((u_hat >= 0) & (u_hat <= 100)).all()

    def test_transition_pairs_skip_episode_boundaries(self) -> None:
        nodes = np.arange(4 * 2, dtype=np.float32).reshape(4, 2, 1, 1)  # (T=4, envs=2, N=1, F=1)
        starts = np.array([[1, 1], [0, 0], [1, 0], [0, 0]], dtype=np.float32)
        previous, current = transition_pairs(
            nodes, starts, np.full((2, 1, 1), 99.0, dtype=np.float32), np.array([0, 1])
        )
        pairs = sorted(zip(previous.ravel().tolist(), current.ravel().tolist()))
        # env 0: rows 0,2,4,6 with a restart at row 2 (value 4); env 1: rows 1,3,5,7, ends done.
        assert pairs == [(0.0, 2.0), (1.0, 3.0), (3.0, 5.0), (4.0, 6.0), (5.0, 7.0), (6.0, 99.0)]


class TestPolicy:
    def test_optimizers_are_disjoint_and_cover_everything(self, env: SingleAgentMonitoringEnv) -> None:
        policy = make_policy(env)
        assert policy.estimator is not None and policy.estimator_optimizer is not None
        ppo = {id(p) for group in policy.optimizer.param_groups for p in group["params"]}
        est = {id(p) for group in policy.estimator_optimizer.param_groups for p in group["params"]}
        assert ppo and est and not ppo & est
        assert ppo | est == {id(p) for p in policy.parameters()}
        assert est == {id(p) for p in policy.estimator.parameters()}

    def test_without_estimator_one_optimizer_holds_all(self, env: SingleAgentMonitoringEnv) -> None:
        policy = make_policy(env, use_estimator=False)
        assert policy.estimator is None and policy.estimator_optimizer is None
        ppo = {id(p) for group in policy.optimizer.param_groups for p in group["params"]}
        assert ppo == {id(p) for p in policy.parameters()}

    def test_estimator_output_enters_detached(self, env: SingleAgentMonitoringEnv) -> None:
        policy = make_policy(env)
        obs = observation_batch(env)
        actions = th.zeros(8, dtype=th.long)
        values, log_prob, entropy = policy.evaluate_actions(obs, actions)
        (values.sum() + log_prob.sum() + entropy.sum()).backward()
        assert all(p.grad is None for p in policy.estimator.parameters())  # type: ignore[union-attr]
        assert any(p.grad is not None for p in policy.features_extractor.parameters())

    def test_masks_follow_the_flags(self, env: SingleAgentMonitoringEnv) -> None:
        obs = observation_batch(env, steps=16)
        reachable = obs["action_mask"].bool()
        filtered = make_policy(env).compute_masks(obs)
        unfiltered = make_policy(env, use_dcbf=False).compute_masks(obs)
        assert th.equal(unfiltered, reachable)
        assert not (filtered & ~reachable).any() and filtered.any(-1).all()

    def test_deterministic_predict_stays_in_the_dcbf_mask(self, env: SingleAgentMonitoringEnv) -> None:
        policy = make_policy(env, use_estimator=False)
        obs = observation_batch(env, steps=16)
        masks = policy.compute_masks(obs)
        actions, _ = policy.predict({k: v.numpy() for k, v in obs.items()}, deterministic=True)
        assert masks[th.arange(16), th.as_tensor(actions)].all()

    def test_actor_first_layer_split_matches_concatenation(self, env: SingleAgentMonitoringEnv) -> None:
        policy = make_policy(env)
        embeddings, own = th.randn(3, N, 33), th.randn(3, 32)
        expanded = th.cat((embeddings, own.unsqueeze(1).expand(-1, N, -1)), dim=-1)
        th.testing.assert_close(policy._actor_hidden(embeddings, own), policy.actor_body(expanded))

    def test_collection_sampling_matches_the_masked_distribution(self, env: SingleAgentMonitoringEnv) -> None:
        """forward_with_masks' inline sampling: same log-probabilities as MaskableCategorical."""
        policy = make_policy(env)
        obs = observation_batch(env)
        actions, _, log_probs, masks = policy.forward_with_masks(obs)
        assert masks.gather(-1, actions.unsqueeze(-1)).all()
        _, expected, _ = policy.evaluate_actions(obs, actions, action_masks=masks)
        th.testing.assert_close(log_probs, expected)

    def test_encoder_settings_in_features_extractor_kwargs_are_not_overridden(self, env) -> None:
        """hidden_dim given in features_extractor_kwargs used to be replaced by the policy's 32."""
        with pytest.raises(ValueError, match=r"hidden_dim \(pass hidden_dim=...\)"):
            make_policy(env, features_extractor_kwargs={"hidden_dim": 64})
        with pytest.raises(ValueError, match="pass gat_backend="):
            make_policy(env, features_extractor_kwargs={"backend": "sparse"})
        # The same value twice is no conflict (a policy saved by SB3 passes both), and the policy's
        # own argument sets the encoder.
        policy = make_policy(env, hidden_dim=16, features_extractor_kwargs={"hidden_dim": 16})
        assert policy.features_extractor.hidden_dim == 16

    def test_masked_mode_equals_the_distribution_mode(self, env: SingleAgentMonitoringEnv) -> None:
        """The deterministic shortcut picks what sb3-contrib's distribution would, ties included."""
        from sb3_pm.policies.heads import masked_mode

        policy = make_policy(env)
        generator = th.Generator().manual_seed(0)
        logits = th.randn(256, N, generator=generator)
        logits[:64] = th.round(logits[:64])  # many exact ties
        logits[64:96] = 0.0  # every entry tied
        masks = th.rand(256, N, generator=generator) < 0.4
        masks[th.arange(256), th.randint(0, N, (256,), generator=generator)] = True  # no empty row
        expected = policy._distribution(logits, masks).get_actions(deterministic=True)
        assert th.equal(masked_mode(logits, masks), expected)
        # And through predict: the shortcut against the distribution on real observations.
        batch = observation_batch(env, steps=16)
        with th.no_grad():
            fast = policy._predict(batch, deterministic=True)
            slow = policy.get_distribution(batch).get_actions(deterministic=True)
        assert th.equal(fast, slow)

    def test_rejects_other_spaces(self) -> None:
        from gymnasium import spaces

        with pytest.raises(ValueError, match="mental-map"):
            DCBFActorCriticPolicy(spaces.Box(0, 1, (3,)), spaces.Discrete(3), lambda _: 1e-3)
