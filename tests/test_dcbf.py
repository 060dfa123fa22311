"""The DCBF filter's rules (docs/METHOD.md "DCBF safety filter") on hand-built tensors."""

from __future__ import annotations

import pytest
import torch as th

from sb3_pm.envs.mental_map import AGE, OCCUPIED, TARGET, U
from sb3_pm.policies.dcbf import DCBFConfig, dcbf_mask, dcbf_mask_from_map

N = 6


def run(
    u_hat: list[float],
    reachable: list[int],
    position: int = 0,
    on_target: bool = False,
    u_here: float = 0.0,
    dwell: float = 0.0,
    occupied: list[int] | None = None,
    **config: float | bool | int,
) -> list[int]:
    """One-row call of :func:`dcbf_mask`; returns the indices allowed."""
    mask = dcbf_mask(
        th.tensor([u_hat], dtype=th.float32),
        th.tensor([[i in reachable for i in range(N)]]),
        th.tensor([position]),
        th.tensor([on_target]),
        th.tensor([u_here]),
        th.tensor([dwell]),
        th.tensor([[i in (occupied or []) for i in range(N)]]),
        DCBFConfig(**config),  # type: ignore[arg-type]
    )
    assert mask.shape == (1, N) and mask.dtype == th.bool
    return th.nonzero(mask[0]).flatten().tolist()


class TestSafeSet:
    def test_only_reachable_nodes_above_h(self) -> None:
        # max û = 10 (node 5, unreachable) -> h = 9; reachable {0, 1, 2, 3}: 1 (9.5) and 3 (9) pass.
        assert run([0, 9.5, 8.9, 9.0, 0, 10], reachable=[0, 1, 2, 3]) == [1, 3]

    def test_eta_widens_the_set(self) -> None:
        assert run([0, 9.5, 8.9, 9.0, 0, 10], reachable=[0, 1, 2, 3], eta=0.2) == [1, 2, 3]

    def test_all_zero_allows_the_whole_reachable_set(self) -> None:
        assert run([0.0] * N, reachable=[0, 2, 4]) == [0, 2, 4]


class TestEmptySetFallback:
    def test_best_reachable_node(self) -> None:
        # max û = 50 far away; reachable nodes all below h = 45: keep the best one.
        assert run([1, 3, 2, 0, 0, 50], reachable=[0, 1, 2]) == [1]

    def test_ties_are_kept(self) -> None:
        assert run([3, 1, 3, 0, 0, 50], reachable=[0, 1, 2]) == [0, 2]


class TestWithoutBarrier:
    def test_whole_reachable_set(self) -> None:
        # The barrier would keep node 1 only; without it every reachable node is allowed.
        assert run([1, 3, 2, 0, 0, 50], reachable=[0, 1, 2], barrier=False) == [0, 1, 2]

    def test_freeze_and_rule_6_still_apply(self) -> None:
        assert run([0, 9, 0, 0, 0, 0], reachable=[0, 1], on_target=True, u_here=4, barrier=False) == [0]
        assert run([0] * N, reachable=[0, 1, 2], occupied=[1], avoid_collisions=True, barrier=False) == [0, 2]


class TestFreeze:
    def test_freeze_on_arrival_at_a_target(self) -> None:
        assert run([0, 50, 0, 0, 0, 0], reachable=[0, 1], on_target=True, u_here=4, dwell=0) == [0]

    def test_freeze_lasts_freeze_steps(self) -> None:
        kwargs = dict(reachable=[0, 1], on_target=True, u_here=4)
        assert run([0, 50, 0, 0, 0, 0], dwell=9, **kwargs) == [0]  # type: ignore[arg-type]
        assert run([0, 50, 0, 0, 0, 0], dwell=10, **kwargs) == [1]  # type: ignore[arg-type]
        assert run([0, 50, 0, 0, 0, 0], dwell=2, freeze_steps=2, **kwargs) == [1]  # type: ignore[arg-type]

    def test_freeze_ends_early_when_u_is_zero(self) -> None:
        assert run([0, 50, 0, 0, 0, 0], reachable=[0, 1], on_target=True, u_here=0, dwell=3) == [1]

    def test_no_freeze_off_target(self) -> None:
        assert run([0, 50, 0, 0, 0, 0], reachable=[0, 1], on_target=False, u_here=4, dwell=0) == [1]

    def test_freeze_disabled(self) -> None:
        assert run([0, 50, 0, 0, 0, 0], reachable=[0, 1], on_target=True, u_here=4, freeze_steps=0) == [1]


class TestAvoidCollisions:
    def test_drops_occupied_nodes(self) -> None:
        u_hat = [0, 10, 10, 0, 0, 0]
        assert run(u_hat, reachable=[0, 1, 2], occupied=[1]) == [1, 2]  # off by default
        assert run(u_hat, reachable=[0, 1, 2], occupied=[1], avoid_collisions=True) == [2]

    def test_unless_that_empties_the_set(self) -> None:
        u_hat = [0, 10, 0, 0, 0, 0]
        assert run(u_hat, reachable=[0, 1, 2], occupied=[1], avoid_collisions=True) == [1]

    def test_frozen_agent_is_never_left_without_a_move(self) -> None:
        mask = run(
            [0, 50, 0, 0, 0, 0],
            reachable=[0, 1],
            on_target=True,
            u_here=4,
            occupied=[0],
            avoid_collisions=True,
        )
        assert mask == [0]


class TestThreshold:
    def test_inactive_below_gamma(self) -> None:
        u_hat = [0, 4, 0, 0, 0, 0]
        assert run(u_hat, reachable=[0, 1, 2], gamma_threshold=5.0) == [0, 1, 2]
        assert run(u_hat, reachable=[0, 1, 2], gamma_threshold=4.0) == [1]

    def test_gamma_also_gates_the_freeze(self) -> None:
        assert run([0] * N, reachable=[0, 1], on_target=True, u_here=4, gamma_threshold=1.0) == [0, 1]


def test_never_all_false_on_random_batches() -> None:
    generator = th.Generator().manual_seed(0)
    batch = 512
    reachable = th.rand(batch, N, generator=generator) < 0.4
    position = th.randint(0, N, (batch,), generator=generator)
    reachable[th.arange(batch), position] = True
    for avoid in (False, True):
        mask = dcbf_mask(
            th.randint(0, 5, (batch, N), generator=generator).float(),
            reachable,
            position,
            th.rand(batch, generator=generator) < 0.5,
            th.randint(0, 3, (batch,), generator=generator).float(),
            th.randint(0, 12, (batch,), generator=generator).float(),
            th.rand(batch, N, generator=generator) < 0.5,
            DCBFConfig(avoid_collisions=avoid),
        )
        assert mask.any(-1).all()
        assert not (mask & ~reachable).any()


def test_even_an_empty_reachable_set_gives_a_row() -> None:
    mask = dcbf_mask(
        th.zeros(1, N),
        th.zeros(1, N, dtype=th.bool),
        th.tensor([0]),
        th.tensor([False]),
        th.zeros(1),
        th.zeros(1),
        th.zeros(1, N, dtype=th.bool),
    )
    assert mask.all()


def test_from_map_reads_the_observation() -> None:
    nodes = th.zeros(1, N, 5)
    nodes[0, 2, TARGET] = 1.0
    nodes[0, 2, U] = 7.0  # the agent stands on target 2 and sees u = 7 -> freeze
    nodes[0, 3, OCCUPIED] = 1.0
    nodes[0, 3, AGE] = 0.0
    position = th.nn.functional.one_hot(th.tensor([2]), N).float()
    observations = {
        "nodes": nodes,
        "position": position,
        "dwell": th.tensor([[0.0]]),
        "action_mask": th.tensor([[0, 1, 1, 1, 0, 0]], dtype=th.float32),
    }
    u_hat = th.tensor([[0.0, 8.5, 7.0, 9.0, 0.0, 0.0]])
    assert th.nonzero(dcbf_mask_from_map(observations, u_hat)[0]).flatten().tolist() == [2]
    observations["dwell"] = th.tensor([[10.0]])
    assert th.nonzero(dcbf_mask_from_map(observations, u_hat)[0]).flatten().tolist() == [1, 3]
    # Node 3 holds another agent, observed now: avoided.
    avoid = DCBFConfig(avoid_collisions=True)
    assert th.nonzero(dcbf_mask_from_map(observations, u_hat, avoid)[0]).flatten().tolist() == [1]
    nodes[0, 3, AGE] = 1.0  # stale occupancy is not avoided
    assert th.nonzero(dcbf_mask_from_map(observations, u_hat, avoid)[0]).flatten().tolist() == [1, 3]


def test_config_validation() -> None:
    with pytest.raises(ValueError, match="eta"):
        DCBFConfig(eta=1.5)
    with pytest.raises(ValueError, match="freeze_steps"):
        DCBFConfig(freeze_steps=-1)
