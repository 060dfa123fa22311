"""The DCBF filter's rules that read the advised node (the env's ``advice_input``): rule 10,
``pass_held`` (an agent off targets whose advised next node holds another agent waits one step,
then takes that node if it is still held), and rule 11, ``keep_moving`` (an agent off targets
advised on to a free node does not stay). Off unless set, usually switched on after training by a
team's ``deploy_filter`` or ``sb3-pm evaluate --pass-held on`` / ``--keep-moving on``."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch as th

from sb3_pm.envs import persistent_monitoring_v0
from sb3_pm.envs.mental_map import AGE, OCCUPIED, TARGET
from sb3_pm.errors import InputError
from sb3_pm.policies.dcbf import DCBFConfig, check_deploy_filter, dcbf_filter_from_map, dcbf_mask
from tests.conftest import path_graph
from tests.test_advice_input import KNOWN, small_team
from tests.test_leave_cleared import N
from tests.test_leave_cleared import allowed as rule_allowed


def allowed(
    reachable: list[int],
    advice: int | None = 1,
    occupied: list[int] | None = None,
    on_target: bool = False,
    dwell: float = 0.0,
    deadline: list[int] | None = None,
    **config: object,
) -> list[int]:
    """The nodes the filter allows an agent on node 0, off targets by default, just arrived and
    advised to go to node 1 (:func:`tests.test_leave_cleared.allowed` with these defaults)."""
    return rule_allowed(
        reachable,
        on_target=on_target,
        u_here=0.0,
        occupied=occupied,
        deadline=deadline,
        dwell=dwell,
        advice=advice,
        **config,
    )


class TestRule:
    def test_off_by_default_a_held_advised_node_changes_nothing(self) -> None:
        assert allowed([0, 1, 2], occupied=[1]) == [0, 1, 2]

    def test_on_the_agent_waits_a_step_then_takes_the_node(self) -> None:
        assert allowed([0, 1, 2], occupied=[1], pass_held=True) == [0]
        assert allowed([0, 1, 2], occupied=[1], dwell=1.0, pass_held=True) == [1]

    def test_it_overrides_rule_6_which_would_turn_the_agent_away_for_good(self) -> None:
        assert allowed([0, 1, 2], occupied=[1], dwell=1.0, avoid_collisions=True) == [0, 2]
        assert allowed([0, 1, 2], occupied=[1], dwell=1.0, avoid_collisions=True, pass_held=True) == [1]

    def test_only_where_the_advised_node_is_held_by_another_and_the_agent_is_off_targets(self) -> None:
        assert allowed([0, 1, 2], occupied=[2], pass_held=True) == [0, 1, 2]  # another node held
        assert allowed([0, 1, 2], occupied=[1], on_target=True, pass_held=True) == [0, 1, 2]
        assert allowed([0, 1, 2], advice=0, occupied=[0], pass_held=True) == [0, 1, 2]  # advised to stay

    def test_the_neglect_bound_overrides_it_and_the_activation_threshold_gates_it(self) -> None:
        assert allowed([0, 1, 2], occupied=[1], deadline=[2], pass_held=True) == [2]
        # max û = 0 < γ: the filter is off, the mask is the reachable set
        assert allowed([0, 1, 2], occupied=[1], gamma_threshold=1.0, pass_held=True) == [0, 1, 2]

    def test_an_agent_that_already_stood_a_step_takes_the_node_at_once(self) -> None:
        """``dwell`` counts every step on the node, so an agent standing there before the block
        does not wait again; an advised node out of reach keeps it where it is."""
        assert allowed([0, 1, 2], occupied=[1], dwell=7.0, pass_held=True) == [1]
        assert allowed([0, 2], advice=1, occupied=[1], dwell=1.0, pass_held=True) == [0]

    def test_an_agent_on_a_target_is_left_to_the_other_rules(self) -> None:
        """Rule 10 leaves agents on targets alone: on a cleared target whose only way on is held,
        rule 6 keeps the agent there (the case the rule does not handle)."""
        kept = allowed([0, 1], occupied=[1], on_target=True, dwell=5.0, avoid_collisions=True, pass_held=True)
        assert kept == [0]

    def test_without_the_advised_node_it_is_refused_by_name(self) -> None:
        with pytest.raises(InputError, match=r"\(rules 10, 11\) need the advised node"):
            allowed([0, 1], advice=None, pass_held=True)
        with pytest.raises(InputError, match="pass_held must be true or false"):
            DCBFConfig(pass_held="yes")  # type: ignore[arg-type]

    def test_on_random_batches_it_changes_exactly_the_blocked_rows(self) -> None:
        """Against the filter without rule 10: the same mask except on the rows of an agent off
        targets whose advised node (not its own) is held: its own node at dwell 0, else the
        advised one."""
        generator = th.Generator().manual_seed(5)
        batch = 512
        reachable = th.rand(batch, N, generator=generator) < 0.5
        reachable[:, 0] = True
        advice_node = th.randint(0, N, (batch,), generator=generator)
        reachable[th.arange(batch), advice_node] = True
        advice = th.nn.functional.one_hot(advice_node, N).bool()
        on_target = th.rand(batch, generator=generator) < 0.3
        dwell = th.randint(0, 3, (batch,), generator=generator).float()
        occupied = th.rand(batch, N, generator=generator) < 0.3
        inputs = (th.rand(batch, N, generator=generator), reachable, th.zeros(batch, dtype=th.long))
        rest = (on_target, th.ones(batch), dwell, occupied)
        config = {"barrier": False, "avoid_collisions": True, "freeze_steps": 0}
        off = dcbf_mask(*inputs, *rest, DCBFConfig(**config), None, advice)
        on = dcbf_mask(*inputs, *rest, DCBFConfig(**config, pass_held=True), None, advice)
        blocked = ~on_target & (advice & occupied).any(-1) & (advice_node != 0)
        expected = off.clone()
        own = th.nn.functional.one_hot(th.zeros(batch, dtype=th.long), N).bool()
        expected[blocked] = th.where((dwell >= 1)[:, None], advice, own)[blocked]
        assert bool((blocked & (dwell == 0)).any()) and bool((blocked & (dwell >= 1)).any())
        assert th.equal(on, expected)


class TestKeepMoving:
    def test_off_by_default_the_agent_may_stay_off_targets(self) -> None:
        assert allowed([0, 1, 2]) == [0, 1, 2]

    def test_on_it_may_not_stay_where_the_advised_node_is_free(self) -> None:
        assert allowed([0, 1, 2], keep_moving=True) == [1, 2]  # the actor still chooses among the rest
        assert allowed([0, 1, 2], advice=0, keep_moving=True) == [0, 1, 2]  # advised to stay
        assert allowed([0, 1, 2], on_target=True, keep_moving=True) == [0, 1, 2]  # on a target
        assert allowed([0, 1, 2], occupied=[1], keep_moving=True) == [0, 1, 2]  # held: rule 10's case
        assert allowed([0], keep_moving=True) == [0]  # nowhere else to go

    def test_with_rule_10_a_held_node_is_waited_for_and_a_free_one_taken(self) -> None:
        both = {"pass_held": True, "keep_moving": True}
        assert allowed([0, 1, 2], occupied=[1], **both) == [0]
        assert allowed([0, 1, 2], **both) == [1, 2]

    def test_the_neglect_bound_overrides_it(self) -> None:
        assert allowed([0, 1, 2], deadline=[0], keep_moving=True) == [0]

    def test_a_team_without_the_advice_column_refuses_it(self) -> None:
        team = small_team({"territory_input": True})
        try:
            with pytest.raises(InputError, match=r"keep_moving \(a filter rule\) reads the advised node"):
                team.set_filter(keep_moving=True)
        finally:
            team.close()
        with pytest.raises(InputError, match="keep_moving reads the node the env's advice_input flags"):
            small_team({}, keep_moving=True)


def test_the_filter_reads_the_advice_from_the_maps_last_column() -> None:
    """On maps from an env with ``advice_input``, the filter's rule 10 acts on the node the last
    column flags; a map without that column is refused rather than read as advice."""
    env = persistent_monitoring_v0.parallel_env(
        graph=path_graph(8, targets=[0, 7]), n_agents=3, max_cycles=10, advice_input=True, **KNOWN
    )
    observations, _ = env.reset(seed=0)
    batch = {
        key: th.as_tensor(np.stack([observations[a][key] for a in env.agents]))
        for key in ("nodes", "action_mask", "dwell")
    }
    nodes = batch["nodes"].float().clone()
    positions = th.as_tensor([env.unwrapped.positions[i] for i in range(3)]).long()
    nodes[:, :, TARGET] = 0.0  # every agent off targets
    advised = nodes[..., -1].argmax(-1)
    nodes[th.arange(3), advised, OCCUPIED] = 1.0  # every advised node held now
    nodes[th.arange(3), advised, AGE] = 0.0
    maps = {
        "nodes": nodes,
        "action_mask": batch["action_mask"].float(),
        "dwell": th.zeros(3, 1),
        "position_index": positions,
    }
    config = DCBFConfig(barrier=False, pass_held=True)
    mask, _ = dcbf_filter_from_map(maps, th.zeros(3, 8), config)
    moving = (advised != positions) & (nodes[..., -1] > 0.5).any(-1)  # a map may advise nothing
    assert bool(moving.any()) and bool((~moving).any())
    assert th.equal(mask[~moving], batch["action_mask"].bool()[~moving])  # the others as before
    assert th.equal(mask[moving], th.nn.functional.one_hot(positions, 8).bool()[moving])  # they wait
    waited, _ = dcbf_filter_from_map({**maps, "dwell": th.ones(3, 1)}, th.zeros(3, 8), config)
    assert th.equal(waited[moving], th.nn.functional.one_hot(advised, 8).bool()[moving])
    with pytest.raises(InputError, match="need the advised node"):
        dcbf_filter_from_map({**maps, "nodes": nodes[..., :-1]}, th.zeros(3, 8), config)
    env.close()


class TestDeployFilter:
    def test_alone_or_with_a_bound_and_rule_9(self) -> None:
        assert check_deploy_filter({"pass_held": True}) == {
            "neglect_bound": None,
            "neglect_scope": "known",
            "pass_held": True,
        }
        both = check_deploy_filter({"neglect_bound": "auto", "pass_held": True, "leave_cleared": False})
        assert both == {
            "neglect_bound": "auto",
            "neglect_scope": "territory",
            "leave_cleared": False,
            "pass_held": True,
        }

    def test_its_checked_form_checks_again_as_itself(self) -> None:
        """What a saved team's manifest holds is the checked form, read back through the same check."""
        for value in ({"pass_held": True}, {"neglect_bound": "auto", "pass_held": True}):
            checked = check_deploy_filter(value)
            assert check_deploy_filter(checked) == checked

    @pytest.mark.parametrize(
        ("value", "message"),
        [
            ({"pass_held": 1}, "pass_held must be true or false, got 1"),
            ({"pass_held": False}, "pass_held: false alone changes nothing; use null"),
            ({"pass_held": False, "leave_cleared": False}, "leave_cleared, pass_held: false alone"),
        ],
    )
    def test_anything_else_is_refused_by_name(self, value, message) -> None:
        with pytest.raises(InputError, match=message):
            check_deploy_filter(value)


class TestTeam:
    def test_a_team_without_the_advice_column_refuses_it(self) -> None:
        team = small_team({"territory_input": True})  # its last column is the territory's
        try:
            with pytest.raises(InputError, match=r"pass_held \(a filter rule\) reads the advised"):
                team.set_filter(pass_held=True)
            assert not team.models["agent_0"].policy.dcbf_config.pass_held
        finally:
            team.close()
        with pytest.raises(InputError, match="pass_held reads the node the env's advice_input flags"):
            small_team({}, pass_held=True)

    def test_a_team_with_it_acts_under_it_trains_without_it_and_saves_it(self, tmp_path) -> None:
        from stable_baselines3.common.callbacks import BaseCallback

        from sb3_pm.cli import main

        team = small_team({"advice_input": True})
        seen: set[bool] = set()

        class Seen(BaseCallback):
            def _on_step(self) -> bool:
                seen.add(self.model.policy.dcbf_config.pass_held)
                return True

        try:
            team.deploy_filter = {"pass_held": True}
            assert team.acting_record(True) == {"pass_held": True}
            team.learn(16, callback={agent: Seen() for agent in team.agents})
            assert seen == {False}
            assert all(p.dcbf_config.pass_held for p in team.acting_policies().values())
            team.save(tmp_path / "team")
        finally:
            team.close()
        out = tmp_path / "e.json"
        argv = ["evaluate", "--policy", str(tmp_path / "team"), "--graph", "karate", "--agents", "2"]
        argv += ["--episodes", "1", "--steps", "20", "--json", str(out)]
        assert main(argv) == 0
        assert json.loads(out.read_text())["config"]["pass_held"] is True
        assert main([*argv, "--pass-held", "off"]) == 0
        assert "pass_held" not in json.loads(out.read_text())["config"]


def test_a_baseline_refuses_the_flag(capsys) -> None:
    from sb3_pm.cli import main

    assert main(["evaluate", "--policy", "grazing", "--graph", "paper-50", "--pass-held", "on"]) == 2
    assert "--pass-held needs a trained DCBF team" in capsys.readouterr().err
