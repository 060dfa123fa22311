"""PettingZoo's own environment tests, run as PettingZoo runs them on its environments.

Those tests act with unmasked random actions (``action_space(agent).sample()``). The env refuses an
illegal move by default (``illegal_action="raise"``): a policy that moves off the graph has a bug,
and turning its move into a stay silently would hide it. So the suite runs on the env with
``illegal_action="stay"``, the documented setting for random or unmasked actors, through a module
that builds the env as PettingZoo's ``mod.env(...)`` and ``mod.parallel_env(...)`` calls expect.
"""

from __future__ import annotations

import functools
from types import SimpleNamespace
from typing import Any

import matplotlib
import pytest
from pettingzoo.test import api_test, max_cycles_test, parallel_api_test, parallel_seed_test, render_test

from sb3_pm.envs import persistent_monitoring_v0
from sb3_pm.envs.core import IllegalActionError

matplotlib.use("Agg")  # "human" rendering draws on a figure that is never shown

#: The env module with illegal moves made stays (module docstring).
STAY = SimpleNamespace(
    env=functools.partial(persistent_monitoring_v0.env, illegal_action="stay"),
    parallel_env=functools.partial(persistent_monitoring_v0.parallel_env, illegal_action="stay"),
)


def test_parallel_seed_test() -> None:
    parallel_seed_test(functools.partial(STAY.parallel_env, max_cycles=60), num_cycles=60)


def test_max_cycles_test() -> None:
    max_cycles_test(STAY)


def test_render_test() -> None:
    render_test(functools.partial(STAY.env, max_cycles=5))


def test_api_tests() -> None:
    api_test(STAY.env(max_cycles=60), num_cycles=60)
    parallel_api_test(STAY.parallel_env(max_cycles=60), num_cycles=60)


@pytest.mark.parametrize("test", ["seed", "max_cycles"])
def test_the_default_refuses_the_suites_unmasked_random_moves(test: str) -> None:
    """Why the suite runs with ``illegal_action="stay"``: with the default, a random move off the
    graph is an error, not a silent stay."""
    default: Any = persistent_monitoring_v0
    with pytest.raises(IllegalActionError):
        if test == "seed":
            parallel_seed_test(functools.partial(default.parallel_env, max_cycles=60), num_cycles=60)
        else:
            max_cycles_test(default)
