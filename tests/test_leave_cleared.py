"""The DCBF filter's rule 9, ``leave_cleared``: an agent on a target it observes cleared does not
stay there. A rule of the filter (:mod:`sb3_pm.policies.dcbf`), off unless set, usually switched on
after training by a team's ``deploy_filter`` or ``sb3-pm evaluate --leave-cleared on``."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch as th

from sb3_pm.errors import InputError
from sb3_pm.policies.dcbf import DCBFConfig, check_deploy_filter, dcbf_mask
from tests.test_deploy_filter import saved_tiny_team, tiny_team

N = 5


def allowed(
    reachable: list[int],
    on_target: bool = True,
    u_here: float = 0.0,
    occupied: list[int] | None = None,
    deadline: list[int] | None = None,
    dwell: float = 5.0,
    advice: int | None = None,
    **config: object,
) -> list[int]:
    """The nodes :func:`dcbf_mask` allows an agent on node 0 (barrier off, so ``S = R`` first),
    advised to go to node ``advice`` (``None``: no advice column)."""
    forced = None
    if deadline is not None:
        forced = (th.tensor([True]), th.tensor([[i in deadline for i in range(N)]]))
    mask = dcbf_mask(
        th.zeros(1, N),
        th.tensor([[i in reachable for i in range(N)]]),
        th.tensor([0]),
        th.tensor([on_target]),
        th.tensor([u_here]),
        th.tensor([dwell]),
        th.tensor([[i in (occupied or []) for i in range(N)]]),
        DCBFConfig(barrier=False, **config),  # type: ignore[arg-type]
        forced,
        None if advice is None else th.tensor([[i == advice for i in range(N)]]),
    )
    return th.nonzero(mask[0]).flatten().tolist()


class TestRule:
    def test_off_by_default_the_agent_may_stay_on_a_cleared_target(self) -> None:
        assert allowed([0, 1, 2]) == [0, 1, 2]

    def test_on_it_may_not(self) -> None:
        assert allowed([0, 1, 2], leave_cleared=True) == [1, 2]

    def test_only_on_a_cleared_target(self) -> None:
        assert allowed([0, 1, 2], on_target=False, leave_cleared=True) == [0, 1, 2]
        # u > 0: the freeze keeps it there, whatever rule 9 says
        assert allowed([0, 1, 2], u_here=3.0, leave_cleared=True) == [0]

    def test_it_stays_where_there_is_nowhere_else(self) -> None:
        assert allowed([0], leave_cleared=True) == [0]
        # rule 6 removed the one neighbour: staying beats a collision
        assert allowed([0, 1], occupied=[1], avoid_collisions=True, leave_cleared=True) == [0]

    def test_the_neglect_bound_overrides_it(self) -> None:
        assert allowed([0, 1, 2], deadline=[0], leave_cleared=True) == [0]

    def test_on_random_batches_it_drops_exactly_the_stay_on_a_cleared_target(self) -> None:
        """Against the filter without rule 9: the same mask, less the own node (0) on the rows of an
        agent on a cleared target with another node allowed; never an empty row."""
        generator = th.Generator().manual_seed(3)
        batch = 512
        reachable = th.rand(batch, N, generator=generator) < 0.4
        reachable[:, 0] |= th.rand(batch, generator=generator) < 0.8
        reachable[~reachable.any(-1), 1] = True  # an agent can always go somewhere
        on_target = th.rand(batch, generator=generator) < 0.5
        u_here = (th.rand(batch, generator=generator) < 0.5).float()
        inputs = (
            th.rand(batch, N, generator=generator) * 10,
            reachable,
            th.zeros(batch, dtype=th.long),
            on_target,
            u_here,
            th.full((batch,), 20.0),
            th.rand(batch, N, generator=generator) < 0.3,
        )
        off = dcbf_mask(*inputs, DCBFConfig(avoid_collisions=True, barrier=False))
        on = dcbf_mask(*inputs, DCBFConfig(avoid_collisions=True, barrier=False, leave_cleared=True))
        cleared = on_target & (u_here == 0) & off[:, 1:].any(-1)
        expected = off.clone()
        expected[cleared, 0] = False
        assert bool(cleared.any()) and bool((~cleared & on_target & (u_here == 0)).any())
        assert th.equal(on, expected) and bool(on.any(-1).all())

    def test_a_setting_that_is_not_a_bool_is_refused(self) -> None:
        with pytest.raises(InputError, match="leave_cleared must be true or false"):
            DCBFConfig(leave_cleared=1)  # type: ignore[arg-type]


class TestDeployFilter:
    def test_with_or_without_a_bound(self) -> None:
        assert check_deploy_filter({"leave_cleared": True}) == {
            "neglect_bound": None,
            "neglect_scope": "known",
            "leave_cleared": True,
        }
        rule = {"neglect_bound": 50, "neglect_scope": "territory", "leave_cleared": True}
        assert check_deploy_filter(rule) == {
            "neglect_bound": 50.0,
            "neglect_scope": "territory",
            "leave_cleared": True,
        }
        auto = check_deploy_filter({"neglect_bound": "auto", "leave_cleared": False})
        assert auto is not None and auto["leave_cleared"] is False
        assert "leave_cleared" not in (check_deploy_filter({"neglect_bound": 50}) or {})  # only where given

    def test_its_checked_form_checks_again_as_itself(self) -> None:
        """What a saved team's manifest holds is the checked form, read back through the same check."""
        for value in ({"leave_cleared": True}, {"neglect_bound": 50, "leave_cleared": True}):
            checked = check_deploy_filter(value)
            assert check_deploy_filter(checked) == checked

    @pytest.mark.parametrize(
        ("value", "message"),
        [
            ({"leave_cleared": "yes"}, "leave_cleared must be true or false"),
            ({"leave_cleared": True, "neglect_scope": "unserved"}, "scope 'unserved' needs a neglect_bound"),
            ({"leave_cleared": True, "bound": 3}, "unknown key 'bound'"),
            ({"leave_cleared": False}, "leave_cleared: false alone changes nothing; use null"),
            ({"neglect_bound": None}, r"or auto \(or left out, with a switch on\)"),
        ],
    )
    def test_anything_else_is_refused_by_name(self, value, message) -> None:
        with pytest.raises(InputError, match=message):
            check_deploy_filter(value)

    def test_the_team_acts_under_it_trains_without_it_and_keeps_it_through_a_bound_change(self) -> None:
        rule = {"neglect_bound": 15, "neglect_scope": "territory", "leave_cleared": True}
        team = tiny_team(deploy_filter=rule)
        try:
            policy = team.models["agent_0"].policy
            assert policy.dcbf_config.leave_cleared
            seen: set[bool] = set()
            from stable_baselines3.common.callbacks import BaseCallback

            class Seen(BaseCallback):
                def _on_step(self) -> bool:
                    seen.add(self.model.policy.dcbf_config.leave_cleared)
                    return True

            team.learn(10, callback={agent: Seen() for agent in team.agents})
            assert seen == {False}
            assert team.models["agent_0"].policy.dcbf_config.leave_cleared
            team.set_filter(neglect_bound=None)  # e.g. --neglect-bound off, or a site with no bound
            assert team.models["agent_0"].policy.dcbf_config.leave_cleared
            assert team.acting_record(True) == {"leave_cleared": True}
        finally:
            team.close()


class TestWithOtherRules:
    def test_it_does_not_replace_a_bound_the_learners_train_with(self) -> None:
        with pytest.raises(InputError, match="trains with a neglect bound .* keep one of them"):
            tiny_team(deploy_filter={"leave_cleared": True}, policy_kwargs={"neglect_bound": 20.0})

    def test_with_auto_it_acts_before_the_site_is_calibrated_and_after(self) -> None:
        from sb3_pm.evaluation.neglect_calibration import settle_site_bound, unsettle_site_bound

        team = tiny_team(deploy_filter={"neglect_bound": "auto", "leave_cleared": True})
        try:
            policy = team.models["agent_0"].policy
            assert team.site_bound_pending and policy.dcbf_config.leave_cleared
            calibration = settle_site_bound(team, team.graph, 2, {}, max_cycles=20)
            assert calibration.bound is not None and not team.site_bound_pending
            assert policy.dcbf_config.neglect_bound == calibration.bound and policy.dcbf_config.leave_cleared
            unsettle_site_bound(team)
            assert policy.dcbf_config.neglect_bound is None and policy.dcbf_config.leave_cleared
        finally:
            team.close()

    def test_a_team_moved_to_another_graph_keeps_it(self) -> None:
        from tests.conftest import path_graph

        team = tiny_team(deploy_filter={"leave_cleared": True}, policy_kwargs={"laplacian": "none"})
        try:
            moved = team.on_graph(path_graph(12, targets=[0, 5, 11]))
            assert all(p.dcbf_config.leave_cleared for p in moved.acting_policies().values())
            assert moved.acting_record(True) == {"leave_cleared": True}
        finally:
            team.close()


@pytest.fixture(scope="module")
def saved(tmp_path_factory) -> Path:
    """A trained two-agent team saved with rule 9 and a territory bound as its deploy filter."""
    rule = {"neglect_bound": 15.0, "neglect_scope": "territory", "leave_cleared": True}
    return saved_tiny_team(tmp_path_factory.mktemp("leave") / "team", deploy_filter=rule)


class TestCommandLine:
    def evaluate(self, saved: Path, tmp_path: Path, *flags: str) -> dict:
        from sb3_pm.cli import main

        out = tmp_path / "e.json"
        argv = ["evaluate", "--policy", str(saved), "--graph", str(saved / "graph.graphml"), "--agents", "2"]
        assert main([*argv, "--episodes", "1", "--steps", "20", "--json", str(out), *flags]) == 0
        return json.loads(out.read_text())["config"]

    def test_a_saved_team_follows_its_rule_and_says_so(self, saved, tmp_path, capsys) -> None:
        config = self.evaluate(saved, tmp_path)
        assert config["leave_cleared"] is True and config["neglect_bound"] == 15.0
        assert "acts under the filter's rule 9, leave_cleared" in capsys.readouterr().err

    def test_off_lets_it_stay_and_on_turns_it_on_without_a_bound(self, saved, tmp_path) -> None:
        assert "leave_cleared" not in self.evaluate(saved, tmp_path, "--leave-cleared", "off")
        config = self.evaluate(saved, tmp_path, "--leave-cleared", "on", "--neglect-bound", "off")
        assert config["leave_cleared"] is True and "neglect_bound" not in config

    def test_a_baseline_refuses_it(self, capsys) -> None:
        from sb3_pm.cli import main

        assert main(["evaluate", "--policy", "grazing", "--graph", "paper-50", "--leave-cleared", "on"]) == 2
        assert "--leave-cleared needs a trained DCBF team" in capsys.readouterr().err
