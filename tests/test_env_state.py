"""An env copy's plain state (``state_dict`` / ``load_state_dict``) carries it on exactly.

Checkpoints keep env copies this way instead of pickling them: a fresh env built with the same
arguments and given the state must then step exactly as the original, in every configuration whose
running state differs (graph families, failures, territory advice, the ``change`` reward, local
observations).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from sb3_pm.envs import persistent_monitoring_v0
from sb3_pm.errors import InputError
from sb3_pm.plain_state import decode, encode

CONFIGS = {
    "preset": {"graph": "paper-50"},
    "family": {"graph": "family:er"},
    "failures_advice_change": {
        "graph": "paper-50",
        "reward": {"change": 0.1, "momentum": 0.01, "clearing": 0.04},
        "graph_knowledge": "known",
        "target_knowledge": "known",
        "advice_input": True,
        "failure_rate": 0.05,
        "initial_uncertainty": "random",
    },
    "local_shared": {"graph": "paper-50", "observation": "local", "shared_map": True},
    "edges_layout": {"graph": "paper-50", "layout": "edges"},
}


def _plain(value):
    arrays: dict = {}
    tree = json.loads(json.dumps(encode(value, arrays)))  # through JSON, as the file holds it
    return decode(tree, arrays)


def _run(env, rng: np.random.Generator, steps: int) -> list:
    """``steps`` random legal moves (resetting finished episodes), everything they returned."""
    seen = []
    for _ in range(steps):
        if not env.agents:
            env.reset()
        observations = env._observations()
        actions = {a: int(rng.choice(np.flatnonzero(observations[a]["action_mask"]))) for a in env.agents}
        obs, rewards, terminations, truncations, infos = env.step(actions)
        seen.append(
            (
                sorted(rewards.items()),
                {a: {k: np.asarray(v).tolist() for k, v in o.items()} for a, o in obs.items()},
                repr(infos),
                sorted(terminations.items()),
            )
        )
    return seen


@pytest.mark.parametrize("config", CONFIGS.values(), ids=CONFIGS.keys())
def test_a_restored_copy_steps_as_the_original(config) -> None:
    env = persistent_monitoring_v0.parallel_env(n_agents=3, max_cycles=25, **config)
    env.reset(seed=3)
    rng = np.random.default_rng(0)
    _run(env, rng, 40)  # into the second episode
    copy = persistent_monitoring_v0.parallel_env(n_agents=3, max_cycles=25, **config)
    copy.load_state_dict(_plain(env.state_dict()))
    moves = rng.bit_generator.state
    expected = _run(env, rng, 60)
    rng.bit_generator.state = moves
    assert _run(copy, rng, 60) == expected


def test_a_state_for_another_env_is_refused() -> None:
    env = persistent_monitoring_v0.parallel_env(graph="paper-50", n_agents=3)
    env.reset(seed=0)
    other = persistent_monitoring_v0.parallel_env(graph="paper-50", n_agents=2)
    with pytest.raises(InputError):
        other.load_state_dict(_plain(env.state_dict()))


@pytest.mark.parametrize(
    "tree",
    [
        {"__dict__": [[1, 2, 3]]},  # a pair of three
        {"__deque__": [1, 2], "maxlen": -1},  # a maxlen deque refuses
        {"__dict__": 5},  # not a list of pairs
    ],
)
def test_a_malformed_state_entry_is_one_line(tmp_path, tree) -> None:
    import json

    import numpy as np

    from sb3_pm.plain_state import StateFormatError, read_state

    (tmp_path / "state.json").write_text(json.dumps(tree))
    np.savez(tmp_path / "state.npz")
    with pytest.raises(StateFormatError) as error:
        read_state(tmp_path / "state.json", tmp_path / "state.npz")
    assert "\n" not in str(error.value)
