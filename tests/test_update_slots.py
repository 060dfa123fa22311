"""Update slots: at most so many learners in their update phase at once, the same parameters."""

from __future__ import annotations

import threading
from typing import Any

import pytest
import torch as th

from sb3_pm.agents.multiplexing.multiplexer import TeamTimeout
from sb3_pm.agents.multiplexing.update_slots import UpdateSlots, default_update_slots
from sb3_pm.agents.training.team import IndependentPPO
from sb3_pm.errors import InputError
from sb3_pm.graphs import erdos_renyi
from sb3_pm.ppo_dcbf.ppo_dcbf import DCBFPPO

th.set_num_threads(1)
GRAPH = erdos_renyi(14, 0.3, n_targets=4, seed=3)
TINY = {"n_steps": 16, "batch_size": 16, "n_epochs": 2, "policy_kwargs": {"hidden_dim": 8}}


def make_team(concurrent_updates: bool = True, slots: int | None = None) -> IndependentPPO:
    team = IndependentPPO(
        GRAPH,
        n_agents=4,
        n_envs=2,
        seed=0,
        env_kwargs={"max_cycles": 20},
        hyperparams=TINY,
        concurrent_updates=concurrent_updates,
    )
    team.update_slots = slots
    return team


def parameters(team: IndependentPPO) -> list[th.Tensor]:
    return [p.detach().clone() for a in team.agents for p in team.models[a].policy.parameters()]


class UpdateCounter:
    """Wraps ``DCBFPPO.train`` to record how many learners were inside it at once.

    Each learner entering waits (up to ``patience`` seconds) until ``expected`` learners are
    inside, so that the most seen is the most allowed, not what the scheduler happened to overlap.
    """

    def __init__(self, monkeypatch: pytest.MonkeyPatch, expected: int, patience: float = 10.0) -> None:
        self.inside = 0
        self.most = 0
        self.calls = 0
        self.cond = threading.Condition()
        original = DCBFPPO.train

        def train(model: Any) -> None:
            with self.cond:
                self.inside += 1
                self.calls += 1
                self.most = max(self.most, self.inside)
                self.cond.notify_all()
                self.cond.wait_for(lambda: self.inside >= expected, timeout=patience)
            try:
                original(model)
            finally:
                with self.cond:
                    self.inside -= 1

        monkeypatch.setattr(DCBFPPO, "train", train)


def test_slots_count_their_holders() -> None:
    slots = UpdateSlots(2)
    assert slots.take(0, 0.01) and slots.take(1, 0.01)
    assert slots.take(1, 0.01), "a holder taking again keeps its slot"
    assert not slots.take(2, 0.01), "no third slot"
    slots.give_back(3)  # holds none: nothing changes
    assert slots.holders == {0, 1}
    slots.give_back(0)
    slots.give_back(0)  # twice: the second is a no-op
    assert slots.take(2, 0.01) and slots.holders == {1, 2}
    assert not slots.take(0, 0.01)


@pytest.mark.parametrize("count", [0, -1, True, 1.5, "2"])
def test_bad_slot_counts_are_refused(count: Any) -> None:
    with pytest.raises(InputError, match="update slots must be a positive integer"):
        UpdateSlots(count)


def test_default_is_one_slot_per_core_per_thread(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr("sb3_pm.agents.multiplexing.update_slots.usable_cores", lambda: 8)
    monkeypatch.setattr(th, "get_num_threads", lambda: 2)
    assert default_update_slots() == 4
    monkeypatch.setattr(th, "get_num_threads", lambda: 16)
    assert default_update_slots() == 1


@pytest.mark.parametrize("slots", [1, 2])
def test_at_most_that_many_learners_update_at_once(slots: int, monkeypatch: pytest.MonkeyPatch) -> None:
    # Each waits a moment for one learner too many: every other learner is ready to enter by then.
    counter = UpdateCounter(monkeypatch, expected=slots + 1, patience=0.3)
    make_team(slots=slots).learn(64)
    assert counter.calls == 4 * 2  # four learners, two rollouts of 32 steps each
    assert counter.most == slots


def test_without_slots_every_learner_may_update_at_once(monkeypatch: pytest.MonkeyPatch) -> None:
    """The count is what limits the updates: with a slot per learner all four overlap."""
    counter = UpdateCounter(monkeypatch, expected=4)
    make_team(slots=4).learn(64)
    assert counter.most == 4


def test_the_parameters_do_not_depend_on_the_slots() -> None:
    serial = make_team(concurrent_updates=False)
    serial.learn(96)
    want = parameters(serial)
    for slots in (1, 3, None):
        team = make_team(slots=slots)
        team.learn(96)
        assert all(th.equal(a, b) for a, b in zip(parameters(team), want, strict=True)), slots


def test_a_failing_update_gives_its_slot_back(monkeypatch: pytest.MonkeyPatch) -> None:
    """With one slot, a learner whose train() raises ends the run with its error; the learners
    waiting for its slot do not hang, and the team can train again."""
    team = make_team(slots=1)
    original = DCBFPPO.train
    failing = team.models[team.agents[1]]

    def train(model: Any) -> None:
        if model is failing:
            raise RuntimeError("update failed")
        original(model)

    monkeypatch.setattr(DCBFPPO, "train", train)
    with pytest.raises(RuntimeError, match="update failed"):
        team.learn(64)
    assert team.hub.update_slots is not None and not team.hub.update_slots.holders
    monkeypatch.setattr(DCBFPPO, "train", original)
    team.learn(32)


def test_a_bad_slot_count_is_refused_before_training() -> None:
    team = make_team(slots=0)
    with pytest.raises(InputError, match="update slots must be a positive integer, got 0"):
        team.learn(32)
    assert team.num_timesteps == 0


def first_to_update(monkeypatch: pytest.MonkeyPatch, then: Any) -> list[Any]:
    """Patches ``DCBFPPO.train`` so that the first learner to enter it calls ``then()`` instead of
    updating (whichever learner the scheduler let in first); returns the models that entered."""
    entered: list[Any] = []
    lock = threading.Lock()
    original = DCBFPPO.train

    def train(model: Any) -> None:
        with lock:
            entered.append(model)
            first = len(entered) == 1
        if first:
            then()
        else:
            original(model)

    monkeypatch.setattr(DCBFPPO, "train", train)
    return entered


def test_a_stuck_update_times_the_team_out(monkeypatch: pytest.MonkeyPatch) -> None:
    """The learner waiting for the slot of a learner stuck in its update times the team out, as it
    would waiting for it at the barrier."""
    team = IndependentPPO(
        GRAPH, n_agents=2, n_envs=2, seed=0, env_kwargs={"max_cycles": 20}, hyperparams=TINY, wait_timeout=2.0
    )
    team.update_slots = 1
    stuck = threading.Event()

    def stall() -> None:  # until the other learner gives up waiting (at most 30 s)
        for _ in range(300):
            if team.hub.timed_out is not None:
                break
            stuck.wait(0.1)

    first_to_update(monkeypatch, stall)
    with pytest.raises(TeamTimeout, match="waited more than 2.0 s for an update slot"):
        team.learn(32)


def test_no_update_starts_after_the_team_is_aborted(monkeypatch: pytest.MonkeyPatch) -> None:
    """The slot of a learner whose update raised goes to a waiting learner, which sees the abort
    and gives it back instead of updating."""
    team = make_team(slots=1)

    def fail() -> None:
        raise RuntimeError("update failed")

    entered = first_to_update(monkeypatch, fail)
    with pytest.raises(RuntimeError, match="update failed"):
        team.learn(32)
    assert len(entered) == 1, "a learner updated after the team was aborted"
