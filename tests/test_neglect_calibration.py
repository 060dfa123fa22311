"""``--neglect-bound auto``: the territory bound a site allows, calibrated on ``territory_patrol``
(:mod:`sb3_pm.evaluation.neglect_calibration`)."""

from __future__ import annotations

import math

import pytest

from sb3_pm.baselines import make_team
from sb3_pm.errors import InputError
from sb3_pm.evaluation import evaluate
from sb3_pm.evaluation.neglect_calibration import CalibratedBound, calibrate_neglect_bound
from tests.conftest import path_graph

#: Two adjacent pairs of targets at the ends of a 10-node path: two agents can hold them.
PAIRS = path_graph(10, targets=[0, 1, 8, 9])


def test_the_bound_is_the_worst_peak_of_the_territory_rule_times_the_margin() -> None:
    rule = evaluate(make_team("territory_patrol"), PAIRS, n_agents=2, episodes=3, seed=5, max_cycles=40)
    peak = max(record.metrics["peak_uncertainty"] for record in rule.episodes)
    assert 0 < peak < 100  # the rule holds the pairs, after walking to them
    found = calibrate_neglect_bound(PAIRS, 2, episodes=3, seed=5, max_cycles=40)
    assert found.peak == peak and found.bound == max(1, math.ceil(peak))  # the default margin, 1
    assert found == calibrate_neglect_bound(PAIRS, 2, episodes=3, seed=5, max_cycles=40)  # seeded
    wider = calibrate_neglect_bound(PAIRS, 2, episodes=3, seed=5, max_cycles=40, margin=1.2)
    assert wider.peak == peak and wider.bound == max(1, math.ceil(1.2 * peak))
    assert f"neglect bound {found.bound:g} on each agent's territory" in found.describe()


def test_no_bound_where_the_territory_rule_lets_a_target_reach_u_max() -> None:
    # One agent for two targets 29 hops apart: whichever it leaves climbs to the cap of 10.
    far = path_graph(30, targets=[0, 29])
    found = calibrate_neglect_bound(far, 1, env_kwargs={"u_max": 10}, episodes=2, max_cycles=100)
    assert (found.bound, found.peak, found.u_max) == (None, 10.0, 10.0)
    assert "cannot be held" in found.describe() and found.to_dict()["bound"] is None
    # The same site with a cap the rule stays under gets a bound.
    roomy = calibrate_neglect_bound(far, 1, env_kwargs={"u_max": 100}, episodes=2, max_cycles=100)
    assert roomy.bound is not None


def test_the_bound_is_at_most_u_max_and_says_so() -> None:
    found = calibrate_neglect_bound(PAIRS, 2, episodes=2, max_cycles=40, margin=50.0)
    assert found.peak * 50 > 100 and found.bound == 100.0 and found.capped
    assert "capped at u_max 100" in found.describe()
    assert not calibrate_neglect_bound(PAIRS, 2, episodes=2, max_cycles=40).capped


def test_a_rule_that_never_leaves_its_targets_gives_the_least_bound() -> None:
    # Two agents start on the two targets, each a territory of one: the rule stays, u stays 0.
    found = calibrate_neglect_bound(
        path_graph(4, targets=[0, 1]), 2, env_kwargs={"initial_positions": [0, 1]}, episodes=2, max_cycles=30
    )
    assert (found.peak, found.bound) == (0.0, 1.0)


def test_random_initial_uncertainty_is_refused() -> None:
    # Rule 8 projects an unseen target from u = 0; with random starts the guarantee does not hold.
    with pytest.raises(InputError, match="initial_uncertainty 'random'"):
        calibrate_neglect_bound(PAIRS, 2, env_kwargs={"initial_uncertainty": "random"})


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"episodes": 0}, "calibration episodes must be at least 1"),
        ({"margin": 0.5}, "margin must be at least 1"),
    ],
)
def test_bad_settings_are_refused(kwargs: dict, message: str) -> None:
    with pytest.raises(InputError, match=message):
        calibrate_neglect_bound(PAIRS, 2, **kwargs)


def test_the_record_names_the_rule() -> None:
    found = CalibratedBound(
        bound=53.0,
        peak=44.0,
        u_max=100.0,
        episodes=10,
        seed=9_000_000,
        margin=1.2,
        n_agents=4,
        max_cycles=500,
    )
    assert found.to_dict() == {
        "rule": "auto",
        "bound": 53.0,
        "peak": 44.0,
        "u_max": 100.0,
        "episodes": 10,
        "seed": 9_000_000,
        "margin": 1.2,
        "n_agents": 4,
        "max_cycles": 500,
    }
