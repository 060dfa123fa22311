"""A learner's update phase on another device (``update_device``): rollouts stay on the learner's
own device, and the update leaves everything where it found it.

On a machine without a GPU the move runs between ``cpu`` and ``cpu:0`` (two device objects that
compare unequal), which exercises every step of it (policy, optimizer state, rollout buffer,
``model.device``) with the same arithmetic, so the parameters must be the plain run's bit for bit.
The CUDA test runs where torch sees a GPU.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import torch as th

from sb3_pm.agents.training.team import IndependentPPO
from sb3_pm.errors import InputError
from sb3_pm.ppo_dcbf import update_device as update_device_module
from sb3_pm.ppo_dcbf.update_device import check_update_device, on_update_device
from tests.test_rollout_batching import make_team, parameters  # a 3-agent team on a 14-node graph

th.set_num_threads(1)


@pytest.mark.parametrize("concurrent_updates", [True, False])
def test_a_moved_update_trains_the_same_parameters(
    monkeypatch: pytest.MonkeyPatch, concurrent_updates: bool
) -> None:
    moves: list[str] = []
    original = update_device_module._move

    def recorded(model: Any, device: th.device) -> None:
        moves.append(str(device))
        original(model, device)

    monkeypatch.setattr(update_device_module, "_move", recorded)
    plain, moved = (
        make_team(concurrent_updates=concurrent_updates),
        make_team(concurrent_updates=concurrent_updates),
    )
    moved.update_device = "cpu:0"
    assert moved.update_device == th.device("cpu:0") and plain.update_device is None
    for team in (plain, moved):
        team.learn(64)
    # 64 steps of 2 envs x 16 steps: two updates per learner, each moved there and back
    assert moves.count("cpu:0") == moves.count("cpu") == 2 * len(moved.agents)
    for a, b in zip(parameters(plain), parameters(moved), strict=True):
        assert th.equal(a, b)
    for agent in moved.agents:
        model = moved.models[agent]
        assert model.device == th.device("cpu") and model.rollout_buffer.device == th.device("cpu")
        moments = [v for state in model.policy.optimizer.state.values() for v in state.values()]
        assert moments and all(v.device == th.device("cpu") for v in moments)
    moved.close()
    plain.close()


def test_inside_the_update_everything_is_on_the_update_device(monkeypatch: pytest.MonkeyPatch) -> None:
    """On the CPU the move's copies show it: ``.to("cpu:0")`` copies a CPU tensor, so the moments
    a learner's second update starts with are other tensors than those its first one ended with."""
    from sb3_contrib import MaskablePPO

    def moments(model: Any) -> list[th.Tensor]:
        return [v for state in model.policy.optimizer.state.values() for k, v in state.items() if k != "step"]

    devices: list[tuple[th.device, th.device]] = []
    # per learner, the moments at each update's start and end (the tensors kept alive)
    starts: dict[int, list[list[th.Tensor]]] = {}
    ends: dict[int, list[list[th.Tensor]]] = {}
    train = MaskablePPO.train

    def recorded(model: Any) -> None:
        devices.append((model.device, model.rollout_buffer.device))
        starts.setdefault(id(model), []).append(moments(model))
        train(model)
        ends.setdefault(id(model), []).append(moments(model))

    monkeypatch.setattr(MaskablePPO, "train", recorded)
    team = make_team(concurrent_updates=False)
    team.update_device = "cpu:0"
    team.learn(64)
    assert len(devices) == 6 and all(device == buffer == th.device("cpu:0") for device, buffer in devices)
    for learner in starts:
        first_end, second_start = ends[learner][0], starts[learner][1]
        assert len(first_end) == len(second_start) > 0
        # moved out after the first update and in again before the second: copies, not the same tensors
        assert not {v.data_ptr() for v in first_end} & {v.data_ptr() for v in second_start}
    team.close()


def test_an_update_that_fails_still_moves_back() -> None:
    team = make_team()
    team.learn(32)
    model = team.models[team.agents[0]]
    with pytest.raises(RuntimeError, match="inside"), on_update_device(model, th.device("cpu:0")):
        assert model.device == th.device("cpu:0")
        raise RuntimeError("inside the update")
    assert model.device == th.device("cpu") and model.rollout_buffer.device == th.device("cpu")
    team.close()


def test_bad_devices_are_refused_by_name(monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(InputError, match="'gpu7' is not a torch device"):
        check_update_device("gpu7")
    with pytest.raises(InputError, match="'meta' is a meta device; only cpu and cuda are supported"):
        check_update_device("meta")  # moving there would destroy the parameters
    with pytest.raises(InputError, match="'auto' is for --device"):
        check_update_device("auto")
    monkeypatch.setattr(th.cuda, "is_available", lambda: True)
    monkeypatch.setattr(th.cuda, "device_count", lambda: 1)
    with pytest.raises(InputError, match="'cuda:3' asked for, but torch sees 1 CUDA device"):
        check_update_device("cuda:3")
    monkeypatch.setattr(th.cuda, "is_available", lambda: False)
    with pytest.raises(InputError, match="torch sees no CUDA device"):
        check_update_device("cuda")
    team = make_team()
    with pytest.raises(InputError, match="no CUDA device"):
        team.update_device = "cuda"
    assert team.update_device is None  # the refused setting left nothing behind
    team.close()


def test_learners_without_the_dcbf_algorithm_refuse_it() -> None:
    team = make_team(algo="maskable_ppo")
    with pytest.raises(InputError, match="update_device needs dcbf_ppo learners; this team has MaskablePPO"):
        team.update_device = "cpu:0"
    team.update_device = None  # switching it off is always allowed
    team.close()


def test_it_is_not_saved_with_the_team(tmp_path: Path) -> None:
    team = make_team()
    team.update_device = "cpu:0"
    team.learn(32)
    team.save(tmp_path / "team")
    loaded = IndependentPPO.load(tmp_path / "team")
    assert loaded.update_device is None
    for agent in loaded.agents:
        assert loaded.models[agent].update_device is None
    team.close()
    loaded.close()


@pytest.mark.skipif(not th.cuda.is_available(), reason="needs a CUDA device")
def test_updates_on_the_gpu_keep_the_learner_on_the_cpu() -> None:
    plain, moved = make_team(), make_team()
    moved.update_device = "cuda"
    for team in (plain, moved):
        team.learn(64)
    for a, b in zip(parameters(plain), parameters(moved), strict=True):
        assert a.device == b.device == th.device("cpu")
        # the same rollouts (the same CPU draws); only the update's rounding differs
        assert th.allclose(a, b, atol=1e-4), float((a - b).abs().max())
    for agent in moved.agents:
        moments = [v for state in moved.models[agent].policy.optimizer.state.values() for v in state.values()]
        assert all(v.device == th.device("cpu") for v in moments)
    plain.close()
    moved.close()
