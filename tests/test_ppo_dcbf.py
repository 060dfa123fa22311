"""DCBFPPO: tiny runs over the ablation flags, stored masks, save/load, determinism."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import configure
from stable_baselines3.common.utils import obs_as_tensor

from sb3_pm.callbacks import EstimatorCallback
from sb3_pm.envs.single_agent import SingleAgentMonitoringEnv
from sb3_pm.graphs import erdos_renyi
from sb3_pm.ppo_dcbf import DCBFPPO

GRAPH = erdos_renyi(12, 0.3, n_targets=3, seed=1)
SMALL = dict(hidden_dim=16, gat_heads=2, net_arch=[32], estimator_hidden=[16])


def make_env(**kwargs: Any) -> SingleAgentMonitoringEnv:
    return SingleAgentMonitoringEnv(GRAPH, n_agents=2, max_cycles=20, **kwargs)


def make_model(seed: int = 0, n_steps: int = 16, **policy_kwargs: Any) -> DCBFPPO:
    return DCBFPPO(
        "DCBFPolicy",
        make_env(),
        n_steps=n_steps,
        batch_size=16,
        n_epochs=2,
        seed=seed,
        policy_kwargs={**SMALL, **policy_kwargs},
    )


def collect(model: DCBFPPO) -> None:
    """One rollout into ``model.rollout_buffer`` without training."""
    _, callback = model._setup_learn(model.n_steps, callback=None)
    model.collect_rollouts(model.env, callback, model.rollout_buffer, model.n_steps)  # type: ignore[arg-type]


def flat_actions_and_masks(model: DCBFPPO) -> tuple[np.ndarray, np.ndarray]:
    buffer = model.rollout_buffer
    return buffer.actions.reshape(-1).astype(int), buffer.action_masks.reshape(-1, buffer.mask_dims).astype(
        bool
    )


ABLATIONS = [
    {},
    {"use_dcbf": False},
    {"use_estimator": False},
    {"use_dcbf": False, "use_estimator": False},
    {"avoid_collisions": True},
    {"dcbf_barrier": False, "avoid_collisions": True},
    {"laplacian": "none", "gamma_threshold": 5.0, "gat_backend": "sparse"},
]


@pytest.mark.parametrize(
    "policy_kwargs", ABLATIONS, ids=lambda k: ",".join(f"{a}={b}" for a, b in k.items()) or "paper"
)
def test_learn_runs(policy_kwargs: dict[str, Any]) -> None:
    model = make_model(**policy_kwargs)
    model.learn(32)
    assert model.num_timesteps == 32
    actions, masks = flat_actions_and_masks(model)
    assert masks[np.arange(len(actions)), actions].all()


def test_learn_with_user_callbacks_attaches_the_estimator_once() -> None:
    seen: list[bool] = []

    class Spy(BaseCallback):
        def _on_training_start(self) -> None:
            seen.append(_count_estimator_callbacks(self.locals["callback"]) == 1)

        def _on_step(self) -> bool:
            return True

    make_model().learn(16, callback=[Spy()])
    make_model().learn(16, callback=[Spy(), EstimatorCallback()])
    assert seen == [True, True]


def _count_estimator_callbacks(callback: Any) -> int:
    if isinstance(callback, EstimatorCallback):
        return 1
    return sum(_count_estimator_callbacks(c) for c in getattr(callback, "callbacks", []))


def test_estimator_loss_is_logged() -> None:
    model = make_model()
    model.set_logger(configure(None, []))
    model.learn(32)
    # The last fit (after the last train()) is recorded and not yet dumped.
    assert np.isfinite(model.logger.name_to_value["estimator/loss"])
    assert model.logger.name_to_value["estimator/pairs"] > 0


def test_sampled_actions_stay_inside_their_stored_masks() -> None:
    model = make_model(n_steps=32, avoid_collisions=True)
    collect(model)
    actions, masks = flat_actions_and_masks(model)
    assert masks[np.arange(len(actions)), actions].all()
    assert masks.any(-1).all()
    reachable = model.rollout_buffer.observations["action_mask"].reshape(-1, 12).astype(bool)  # type: ignore[index, call-overload]
    assert not (masks & ~reachable).any()
    assert (masks.sum(-1) < reachable.sum(-1)).any(), "the DCBF should remove some reachable nodes"


def test_train_uses_the_stored_masks() -> None:
    model = make_model(n_steps=32)
    collect(model)
    buffer = model.rollout_buffer
    observations = obs_as_tensor(
        {k: v.reshape(-1, *v.shape[2:]) for k, v in buffer.observations.items()}, model.device
    )  # type: ignore[union-attr]
    actions = th.as_tensor(buffer.actions.reshape(-1)).long()
    stored = th.as_tensor(buffer.action_masks.reshape(-1, buffer.mask_dims))
    with th.no_grad():
        _, log_prob, _ = model.policy.evaluate_actions(observations, actions, action_masks=stored)
    # Right after collection the policy is unchanged: PPO's first ratio is exactly 1.
    th.testing.assert_close(log_prob, th.as_tensor(buffer.log_probs.reshape(-1)), atol=1e-5, rtol=0)

    # Change the estimator so that the DCBF would now produce different masks (random û).
    estimator = model.policy.estimator
    assert estimator is not None
    fixed = th.rand(actions.shape[0], 12, generator=th.Generator().manual_seed(0)) * 100.0
    estimator.forward = lambda nodes: fixed  # type: ignore[method-assign]
    recomputed = model.policy.compute_masks(observations)
    with th.no_grad():
        # (SB3 distributions are shared objects: check the masks before the next call replaces them.)
        assert th.equal(model.policy.get_distribution(observations).distribution.masks, recomputed)  # type: ignore[attr-defined]
        _, log_prob_stored, _ = model.policy.evaluate_actions(observations, actions, action_masks=stored)
        assert th.equal(model.policy.action_dist.distribution.masks, stored.bool())  # type: ignore[attr-defined]
    excluded_now = ~recomputed[th.arange(len(actions)), actions]
    assert excluded_now.any(), "the perturbed estimator should now forbid some sampled actions"
    # Under the stored masks those actions keep a real probability (not the -1e8 of a masked logit).
    assert th.isfinite(log_prob_stored).all() and (log_prob_stored > -20).all()

    # train() must never ask the policy for a fresh mask.
    def fail(*args: Any, **kwargs: Any) -> None:
        raise AssertionError("train() recomputed a mask")

    del estimator.forward  # back to the real network (the fixed û has the full batch's shape)
    model.policy._masks = fail  # type: ignore[method-assign]
    model.policy.compute_masks = fail  # type: ignore[method-assign]
    model.train()


def test_estimator_loss_falls_on_a_fixed_rollout() -> None:
    model = make_model(n_steps=64, estimator_epochs=1, estimator_batch_size=32, estimator_lr=3e-3)
    collect(model)
    callback = EstimatorCallback()
    callback.init_callback(model)
    from sb3_pm.policies.estimator import transition_pairs

    buffer = model.rollout_buffer
    pairs = transition_pairs(buffer.observations["nodes"], buffer.episode_starts)  # type: ignore[index, call-overload]
    first = callback.fit(*pairs)
    for _ in range(30):
        last = callback.fit(*pairs)
    assert last < 0.5 * first


def test_estimator_callback_fits_after_train_by_default() -> None:
    model = make_model(n_steps=16)
    before = [p.detach().clone() for p in model.policy.estimator.parameters()]  # type: ignore[union-attr]
    order: list[str] = []
    original_train = model.train

    def train() -> None:
        changed = any(not th.equal(a, b) for a, b in zip(before, model.policy.estimator.parameters()))  # type: ignore[union-attr]
        order.append("train, estimator changed" if changed else "train")
        original_train()

    model.train = train  # type: ignore[method-assign]
    model.learn(16)
    assert order == ["train"]
    assert any(not th.equal(a, b) for a, b in zip(before, model.policy.estimator.parameters()))  # type: ignore[union-attr]


def test_same_seed_same_parameters() -> None:
    # Build and train one model at a time: SB3 seeds torch's global RNG at construction.
    first = make_model(seed=3).learn(32)
    second = make_model(seed=3).learn(32)
    for (name, a), (_, b) in zip(first.policy.state_dict().items(), second.policy.state_dict().items()):
        assert th.equal(a, b), name
    different = make_model(seed=4)
    different.learn(32)
    assert any(not th.equal(a, b) for a, b in zip(first.policy.parameters(), different.policy.parameters()))


def test_save_load_round_trip(tmp_path: Path) -> None:
    model = make_model(avoid_collisions=True, dcbf_barrier=False)
    model.learn(32)
    path = tmp_path / "dcbf.zip"
    model.save(path)
    loaded = DCBFPPO.load(path, env=make_env())
    assert loaded.policy.avoid_collisions
    assert not loaded.policy.dcbf_config.barrier
    env = make_env()
    obs, _ = env.reset(seed=5)
    for _ in range(20):
        expected, _ = model.predict(obs, deterministic=True)
        action, _ = loaded.predict(obs, deterministic=True)
        assert int(action) == int(expected)
        obs, *_ = env.step(int(action))
    for (name, a), (_, b) in zip(model.policy.state_dict().items(), loaded.policy.state_dict().items()):
        assert th.equal(a, b), name
    saved_state = model.policy.estimator_optimizer.state_dict()  # type: ignore[union-attr]
    loaded_state = loaded.policy.estimator_optimizer.state_dict()  # type: ignore[union-attr]
    assert saved_state["state"].keys() == loaded_state["state"].keys() and len(saved_state["state"]) > 0
    th.testing.assert_close(saved_state["state"][0]["exp_avg"], loaded_state["state"][0]["exp_avg"])


def test_rejects_a_policy_without_dcbf() -> None:
    with pytest.raises(ValueError, match="MlpPolicy"):
        DCBFPPO("MlpPolicy", make_env())



def test_each_update_gives_its_freed_memory_back(monkeypatch: pytest.MonkeyPatch) -> None:
    """Twelve learners updating in their own threads held several GB between updates on a
    1,000-node site until each update trimmed glibc's arenas (docs/RESULTS.md, "Sites of thousands
    of nodes"); the trim runs after every update, and runs at all where there is no glibc."""
    from sb3_pm.machine import release_freed_memory
    from sb3_pm.ppo_dcbf import ppo_dcbf

    release_freed_memory()  # a no-op without glibc, never an error
    calls: list[int] = []
    monkeypatch.setattr(ppo_dcbf, "release_freed_memory", lambda: calls.append(1))
    model = make_model()
    model.learn(32)  # two rollouts of 16 steps: two updates
    assert len(calls) == 2
