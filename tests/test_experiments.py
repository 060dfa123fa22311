"""``sb3-pm reproduce``: quick sweeps end to end, resuming, the Ray backend, and bad input."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import pytest

from sb3_pm.cli import main
from sb3_pm.errors import InputError
from sb3_pm.experiments import ExperimentError, load_experiment, plan_cells, reproduce
from sb3_pm.experiments import runner as runner_module
from sb3_pm.zoo import load_config
from tests.paths import (
    ZOO,
    every_experiment_file,
    experiment_file,
    trains_the_default,
    trains_the_split_default,
)

EXPECTED_FILES = {
    "results.md",
    "results.csv",
    "results.tex",
    "anova.txt",
    "by_graph.md",
    "report.md",
    "effects.md",
    "results.json",
    "uncertainty.png",
    "table.png",
    "runs.md",
    "marl_eval.json",
    "performance_profile.png",
    "training.png",
    "estimator_loss.png",
    "experiment.yml",
    "command.txt",
}


def quick_reproduce(name: str, out: Path) -> list[str]:
    """``sb3-pm reproduce NAME --quick --out OUT`` in one process, without a progress bar."""
    return [
        "reproduce",
        str(experiment_file(name)),
        "--quick",
        "--out",
        str(out),
        "--jobs",
        "1",
        "--no-progress",
    ]


@pytest.mark.parametrize("name", ["comparison", "ablation"])
def test_quick_experiment_runs_end_to_end(tmp_path: Path, name: str) -> None:
    out = tmp_path / name
    assert main(quick_reproduce(name, out)) == 0
    assert EXPECTED_FILES <= {p.name for p in out.iterdir()}
    experiment = load_experiment(experiment_file(name)).quick()
    table = (out / "results.md").read_text()
    for variant in experiment.variants:
        assert variant.label in table
    report = (out / "report.md").read_text()
    assert table.strip() in report and (out / "effects.md").read_text().strip() in report
    trained = [cell for cell in out.glob("cells/*/*/*") if (cell / "team").is_dir()]
    assert trained and all((cell / "machine.yml").is_file() for cell in trained)  # who trained it
    assert "reproduce" in report and "--quick" in report  # the command that made it
    assert "sb3_pm " in report and "![" in report  # the code version and the figures
    runs = (out / "runs.md").read_text()  # the aggregates over training runs, in the report first
    assert "IQM" in runs and "95% CI" in runs and runs.strip() in report
    assert report.index("## Across training runs") < report.index("One-way ANOVA")
    assert "performance_profile.png" in report
    for cell in plan_cells(experiment, out):
        assert (Path(cell.folder) / "DONE").exists()
        if cell.variant["kind"] != "baseline":
            assert (Path(cell.folder) / "team" / "manifest.json").exists()


def _flat(config) -> dict:
    """A training config as one flat ``{(section, key): value}`` mapping, policy kwargs key by key."""
    hyperparams = dict(config.hyperparams)
    policy_kwargs = hyperparams.pop("policy_kwargs", {})
    flat = {("hyperparams", k): v for k, v in hyperparams.items()}
    flat.update({("policy_kwargs", k): v for k, v in policy_kwargs.items()})
    flat.update({("env_kwargs", k): v for k, v in config.env_kwargs.items()})
    flat.update({("team", k): getattr(config, k) for k in ("n_envs", "n_agents", "algo", "policy")})
    return flat


def _against_improved(cell) -> tuple[dict, dict]:
    """The cell's training config and zoo/ippo_improved.yml's for its graph, both as :func:`_flat`."""
    from sb3_pm.zoo.config import load_config

    merged = runner_module.cell_config(cell, runner_module.Variant(**cell.variant))
    return _flat(merged), _flat(load_config(ZOO / "ippo_improved.yml", cell.graph))


def _changes(merged: dict, direct: dict) -> dict:
    """The settings in which ``merged`` differs from ``direct``, with ``merged``'s values."""
    return {
        k: merged.get(k, "unset")
        for k in merged.keys() | direct.keys()
        if merged.get(k, "unset") != direct.get(k, "unset")
    }


def test_tuning_variants_change_one_key_of_the_improved_config(tmp_path: Path) -> None:
    """tuning.yml is a one-change-at-a-time screen: ``improved`` trains zoo/ippo_improved.yml as it
    is, and every ``tune_*`` variant differs from it in exactly one setting."""
    experiment = load_experiment(experiment_file("tuning"))
    learned = [c for c in plan_cells(experiment, tmp_path) if c.variant["kind"] != "baseline" and c.seed == 0]
    assert {c.variant["key"] for c in learned} >= {"improved", "tune_lr_3e3", "tune_reward_01"}
    for cell in learned:
        changed = _changes(*_against_improved(cell))
        # The rollout variant keeps one minibatch per rollout, so it moves n_steps and batch_size.
        expected = {"improved": 0, "tune_rollout_1000": 2}.get(cell.variant["key"], 1)
        assert len(changed) == expected, (cell.variant["key"], changed)


_LR_3E3 = {("hyperparams", "learning_rate"): 0.003}
_REWARD_01 = {("env_kwargs", "reward"): {"reduction": 0.01, "collision": 0.0005}}
_CLEARING = {("env_kwargs", "reward"): {"clearing": 0.04, "collision": 0.001}}


@pytest.mark.parametrize(
    ("name", "expected_changes"),
    [
        (
            "combined",
            {
                "combo_lr_reward": {**_LR_3E3, **_REWARD_01},
                "combo_lr_reward_epochs": {**_LR_3E3, **_REWARD_01, ("hyperparams", "n_epochs"): 20},
            },
        ),
        ("idling", {"clearing": _CLEARING, "clearing_lr_3e3": {**_LR_3E3, **_CLEARING}}),
    ],
)
def test_follow_up_variants_change_exactly_what_they_name(
    tmp_path: Path, name: str, expected_changes: dict
) -> None:
    """The follow-ups of tuning.yml share ``improved`` and ``tune_lr_3e3`` with it (same training
    config, so finished cells can be reused), and each new variant is the improved config plus
    exactly the changes it names."""
    experiment = load_experiment(experiment_file(name))
    tuning = {c.variant["key"]: c for c in plan_cells(load_experiment(experiment_file("tuning")), tmp_path)}
    learned = [c for c in plan_cells(experiment, tmp_path) if c.variant["kind"] != "baseline" and c.seed == 0]
    assert {c.variant["key"] for c in learned} == {"improved", "tune_lr_3e3", *expected_changes}
    for cell in learned:
        merged, direct = _against_improved(cell)
        key = cell.variant["key"]
        if key in expected_changes:
            assert _changes(merged, direct) == expected_changes[key], key
        else:
            assert merged == _against_improved(tuning[key])[0], key


def tiny_experiment(tmp_path: Path) -> Path:
    """One learned variant and one baseline on a 12-node graph, with a tiny training config."""
    from sb3_pm.graphs import erdos_renyi, save_graphml

    save_graphml(erdos_renyi(12, 0.3, n_targets=3, seed=1), tmp_path / "tiny.graphml")
    (tmp_path / "config.yml").write_text(
        "default:\n  n_timesteps: 64\n  n_envs: 1\n  n_steps: 32\n  batch_size: 32\n  n_epochs: 1\n"
        "  policy_kwargs: {hidden_dim: 8, gat_heads: 1}\n"
    )
    (tmp_path / "experiment.yml").write_text(
        "name: tiny\ngraphs: [tiny.graphml]\nseeds: [0, 1]\nepisodes: 2\nmax_cycles: 20\nn_agents: 2\n"
        "config: config.yml\nvariants:\n  learned: {}\n  random: {kind: baseline, policy: random}\n"
    )
    return tmp_path / "experiment.yml"


def size_independent_config(tmp_path: Path) -> None:
    """Make the tiny experiment's team config size-independent (``laplacian: none``), so its team
    runs on graphs of other sizes."""
    path = tmp_path / "config.yml"
    path.write_text(path.read_text().replace("gat_heads: 1}", "gat_heads: 1, laplacian: none}"))


def load_tiny(tmp_path: Path):
    experiment = load_experiment(tiny_experiment(tmp_path))
    # Graph paths in an experiment file are taken as given; make this one absolute for the test.
    return experiment.with_graphs([str(tmp_path / "tiny.graphml")])


def test_resumed_sweep_retrains_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    experiment = load_tiny(tmp_path)
    first = reproduce(experiment, tmp_path / "out", n_jobs=1, progress=False)

    def must_not_train(*args, **kwargs):
        raise AssertionError("a finished cell was trained again")

    monkeypatch.setattr(runner_module, "_train", must_not_train)
    second = reproduce(experiment, tmp_path / "out", n_jobs=1, progress=False)
    assert first.table == second.table


def test_interrupted_sweep_runs_only_the_missing_cells(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    experiment = load_tiny(tmp_path)
    reproduce(experiment, tmp_path / "out", n_jobs=1, progress=False)
    cells = plan_cells(experiment, tmp_path / "out")
    # As if the sweep had died while training cell 1 (no team saved yet) ...
    (Path(cells[1].folder) / "DONE").unlink()
    shutil.rmtree(Path(cells[1].folder) / "team")
    # ... and after training cell 0 (team saved, evaluation not finished): only evaluated again.
    (Path(cells[0].folder) / "DONE").unlink()
    trained = []
    original = runner_module._train

    def counting_train(cell, variant, folder):
        trained.append((cell.variant["key"], cell.seed))
        return original(cell, variant, folder)

    monkeypatch.setattr(runner_module, "_train", counting_train)
    reproduce(experiment, tmp_path / "out", n_jobs=1, progress=False)
    assert trained == [(cells[1].variant["key"], cells[1].seed)]
    assert (Path(cells[0].folder) / "DONE").exists()


def test_a_cell_stopped_mid_training_resumes_from_its_checkpoint(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import torch as th

    from sb3_pm.agents.training import checkpoints as checkpoints_module
    from sb3_pm.agents.training.team import IndependentPPO

    experiment = load_tiny(tmp_path)
    reproduce(experiment, tmp_path / "whole", n_jobs=1, progress=False)

    class Killed(Exception):
        pass

    write_checkpoint = checkpoints_module.write_checkpoint

    def write_then_die(*args):
        write_checkpoint(*args)
        raise Killed  # the sweep dies right after the cell's first checkpoint

    monkeypatch.setattr(runner_module, "CELL_CHECKPOINT_EVERY", 1)
    monkeypatch.setattr(checkpoints_module, "write_checkpoint", write_then_die)
    with pytest.raises(Killed):
        reproduce(experiment, tmp_path / "cut", n_jobs=1, progress=False)
    cut = [Path(c.folder) for c in plan_cells(experiment, tmp_path / "cut") if c.variant["key"] == "learned"]
    assert list((cut[0] / "checkpoints").glob("rollout_*/checkpoint.json"))
    assert not (cut[0] / "team").exists()

    monkeypatch.setattr(checkpoints_module, "write_checkpoint", write_checkpoint)
    calls = []
    learn = IndependentPPO.learn

    def spy(self, total_timesteps, *args, **kwargs):
        calls.append((self.num_timesteps, total_timesteps, kwargs.get("reset_num_timesteps", True)))
        return learn(self, total_timesteps, *args, **kwargs)

    monkeypatch.setattr(IndependentPPO, "learn", spy)
    reproduce(experiment, tmp_path / "cut", n_jobs=1, progress=False)
    assert calls == [(32, 32, False), (0, 64, True)]  # the cut cell continued; the other started
    whole = [
        Path(c.folder) for c in plan_cells(experiment, tmp_path / "whole") if c.variant["key"] == "learned"
    ]
    for resumed, uninterrupted in zip(cut, whole):
        assert not (resumed / "checkpoints").exists()  # the saved team supersedes them
        a, b = IndependentPPO.load(resumed / "team"), IndependentPPO.load(uninterrupted / "team")
        for agent in a.agents:
            for x, y in zip(
                a.models[agent].policy.state_dict().values(), b.models[agent].policy.state_dict().values()
            ):
                assert th.equal(x, y)


def test_update_device_reaches_every_learned_cell(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from sb3_pm.ppo_dcbf import update_device as update_device_module

    experiment = load_tiny(tmp_path)
    plain = reproduce(experiment, tmp_path / "plain", n_jobs=1, progress=False)
    moves: list[str] = []
    move = update_device_module._move

    def recorded(model, device):
        moves.append(str(device))
        move(model, device)

    monkeypatch.setattr(update_device_module, "_move", recorded)
    # cpu:0 is another device object than cpu: each update moves there and back, same arithmetic
    moved = reproduce(experiment, tmp_path / "moved", n_jobs=1, progress=False, update_device="cpu:0")
    assert moved.table == plain.table
    # 2 seeds x 2 learners x 2 updates (64 steps of 32), each moved there and back
    assert moves.count("cpu:0") == moves.count("cpu") == 8
    assert [c.update_device for c in plan_cells(experiment, tmp_path, update_device="cpu:0")] == ["cpu:0"] * 4


def test_an_update_device_for_learners_that_cannot_take_it_is_refused_before_training(tmp_path: Path) -> None:
    experiment = load_tiny(tmp_path)
    config = tmp_path / "config.yml"
    # maskable_ppo's MultiInputPolicy has no GAT encoder: the config loader would refuse hidden_dim
    text = config.read_text().replace("hidden_dim: 8, gat_heads: 1", "net_arch: [8]")
    config.write_text(text + "  algo: maskable_ppo\n")
    with pytest.raises(InputError, match="needs dcbf_ppo learners; variant 'learned' uses maskable_ppo"):
        reproduce(experiment, tmp_path / "out", n_jobs=1, progress=False, update_device="cpu:0")
    assert not (tmp_path / "out" / "cells").exists()  # nothing trained


def test_reproduce_refuses_an_update_device_it_lacks(tmp_path: Path, capsys, monkeypatch) -> None:
    import torch

    path = tiny_experiment(tmp_path)
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    argv = ["reproduce", str(path), "--out", str(tmp_path / "o"), "--update-device", "cuda"]
    assert main([*argv, "--graphs", str(tmp_path / "tiny.graphml")]) == 2
    assert "torch sees no CUDA device" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_ray_backend_matches_local(tmp_path: Path) -> None:
    experiment = load_tiny(tmp_path)
    local = reproduce(experiment, tmp_path / "local", backend="local", n_jobs=1, progress=False)
    distributed = reproduce(experiment, tmp_path / "ray", backend="ray", n_jobs=2, progress=False)
    assert local.table == distributed.table
    for label in local.results:
        assert [r.to_dict() for r in local.results[label]] == [
            r.to_dict() for r in distributed.results[label]
        ]


def test_resume_refuses_a_different_experiment(tmp_path: Path) -> None:
    path = tiny_experiment(tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    (out / "experiment.yml").write_text("name: something else\n")
    assert main(["reproduce", str(path), "--out", str(out), "--graphs", str(tmp_path / "tiny.graphml")]) == 2


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("graphs: [paper-50]\nseeds: [0]\nvariants: {a: {kind: magic}}\n", "kind must be one of"),
        ("graphs: [paper-50]\nseeds: [0]\nvariants: {a: {kind: baseline}}\n", "needs 'policy'"),
        ("graphs: [paper-50]\nseeds: [0]\nvariants: {a: {}}\n", "need 'config'"),
        (
            "graphs: [paper-50]\nseeds: [0]\nvariants: {a: {kind: baseline, policy: random}}\nbudget: 3\n",
            "unknown keys",
        ),
        ("graphs: []\nseeds: [0]\nvariants: {a: {kind: baseline, policy: random}}\n", "'graphs' is required"),
        ("graphs: [paper-50\n", "not valid YAML"),
        (
            "graphs: [paper-50]\nseeds: [0]\nvariants: {a: {kind: baseline, policy: random, train: false}}\n",
            "'train' applies to learned variants",
        ),
        (
            "graphs: [paper-50]\nseeds: [0]\nconfig: x.yml\nvariants: {a: {train: maybe}}\n",
            "'train' must be true",
        ),
        (
            "graphs: [paper-50]\nseeds: [0]\n"
            "variants: {a: {kind: baseline, policy: random, config: x.yml}}\n",
            "'config' applies to learned variants",
        ),
        (
            "graphs: [paper-50]\nseeds: [0]\nvariants: {a: {config: missing.yml}}\n",
            "training config not found",
        ),
        (
            "graphs: [paper-50]\nseeds: [0]\n"
            "variants: {a: {kind: baseline, policy: random, train_env: paper-50}}\n",
            "'train_env' applies to independent variants only",
        ),
        (
            "graphs: [paper-50]\nseeds: [0]\nconfig: x.yml\nvariants: {a: {train_env: family:spiral}}\n",
            "train_env: unknown graph family 'family:spiral'",
        ),
        (
            "graphs: [paper-50]\nseeds: [0]\nconfig: x.yml\nvariants: {a: {timesteps: -3}}\n",
            "'timesteps' must be a positive integer",
        ),
        (
            "graphs: [paper-50]\nseeds: [0]\nconfig: x.yml\nvariants: {a: {train_agents: 4}}\n",
            "'train_agents' applies to independent variants with a train_env",
        ),
        (
            "graphs: [paper-50]\nseeds: [0]\nconfig: x.yml\n"
            "variants: {a: {train_env: paper-50, train_agents: 0}}\n",
            "'train_agents' must be a positive integer, got 0",
        ),
        (
            "graphs: [paper-50]\nseeds: [0]\nconfig: x.yml\nvariants: {a: {train_env: paper-50, "
            "train_agents: 2, agents: {agent_3: {learning_rate: 0.001}}}}\n",
            "unknown agent 'agent_3' \\(the team has agent_0 .. agent_1\\)",
        ),
    ],
)
def test_malformed_experiment_files(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "bad.yml"
    path.write_text(text)
    with pytest.raises(ExperimentError, match=message):
        load_experiment(path)


def test_cli_errors_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["reproduce", str(tmp_path / "missing.yml"), "--out", str(tmp_path / "o")]) == 2
    assert "experiment file not found" in capsys.readouterr().err
    assert (
        main(
            [
                "reproduce",
                str(experiment_file("comparison")),
                "--out",
                str(tmp_path / "o"),
                "--graphs",
                "no-such-graph",
            ]
        )
        == 2
    )
    assert "unknown graph" in capsys.readouterr().err


def test_variants_option_runs_a_subset(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tiny_experiment(tmp_path)
    out = tmp_path / "out"
    graph = str(tmp_path / "tiny.graphml")
    args = ["reproduce", str(path), "--out", str(out), "--no-progress", "--jobs", "1", "--graphs", graph]
    assert main([*args, "--variants", "random"]) == 0
    assert [p.name for p in (out / "cells").iterdir()] == ["random"]
    assert "random" in (out / "experiment.yml").read_text()
    assert "learned" not in (out / "experiment.yml").read_text()
    assert main([*args, "--variants", "nope"]) == 2
    assert "unknown variant(s) ['nope']" in capsys.readouterr().err


def test_cell_results_are_stored(tmp_path: Path) -> None:
    experiment = load_tiny(tmp_path)
    reproduce(experiment, tmp_path / "out", n_jobs=1, progress=False)
    payload = json.loads(
        (Path(plan_cells(experiment, tmp_path / "out")[0].folder) / "evaluation.json").read_text()
    )
    assert len(payload["traces"]) == 2 and len(payload["traces"][0]) == 20


def test_cells_are_scheduled_longest_first(tmp_path: Path) -> None:
    experiment = load_experiment(experiment_file("comparison"))
    cells = plan_cells(experiment, tmp_path)
    order = runner_module.schedule(cells)
    assert sorted(map(id, order)) == sorted(map(id, cells))  # a permutation: nothing lost or doubled
    learned = [runner_module.Variant(**cell.variant).learned for cell in order]
    assert learned == sorted(learned, reverse=True)  # every learned cell before any baseline
    first = order[0]
    assert first.graph == "paper-200" and runner_module.Variant(**first.variant).learned


def test_untrained_variant_evaluates_the_initial_policy(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tiny_experiment(tmp_path)
    text = path.read_text().replace("  learned: {}\n", "  learned: {}\n  untrained: {train: false}\n")
    path.write_text(text)
    experiment = load_experiment(path).with_graphs([str(tmp_path / "tiny.graphml")])
    from sb3_pm.agents.training.team import IndependentPPO

    learned_seeds = []
    original = IndependentPPO.learn

    def recording_learn(self, *args, **kwargs):
        learned_seeds.append(self.seed)
        return original(self, *args, **kwargs)

    monkeypatch.setattr(IndependentPPO, "learn", recording_learn)
    comparison = reproduce(experiment, tmp_path / "out", n_jobs=1, progress=False)
    assert len(learned_seeds) == len(experiment.seeds)  # only the trained variant's cells learned
    assert "untrained" in comparison.results and "learned" in comparison.results
    assert "train: false" in (tmp_path / "out" / "experiment.yml").read_text()
    # The untrained cells saved their teams as built (no step taken); the trained ones did learn.
    for cell in plan_cells(experiment, tmp_path / "out"):
        if cell.variant["kind"] == "baseline":
            continue
        team = IndependentPPO.load(Path(cell.folder) / "team")
        steps = {model.num_timesteps for model in team.models.values()}
        assert (steps == {0}) == (cell.variant["key"] == "untrained"), (cell.variant["key"], steps)


@pytest.mark.parametrize(
    ("key", "changed"),
    [
        ("improved_paper_reward", ("env_kwargs", "reward", "paper")),
        ("improved_barrier", ("policy_kwargs", "dcbf_barrier", True)),
        ("improved_freeze10", ("policy_kwargs", "freeze_steps", 10)),
        ("improved_collisions_allowed", ("policy_kwargs", "avoid_collisions", False)),
        ("improved", None),
    ],
)
def test_improved_variants_are_the_improved_config(tmp_path: Path, key: str, changed: tuple | None) -> None:
    """``improved`` trains exactly zoo/ippo_improved.yml; each ``improved_*`` ablation changes one key."""
    experiment = load_experiment(experiment_file("improvements"))
    cell = next(c for c in plan_cells(experiment, tmp_path) if c.variant["key"] == key)
    merged, direct = _against_improved(cell)
    if changed is not None:
        where, name, value = changed
        direct[(where, name)] = value
    # Hyperparameters, policy kwargs, env kwargs, n_envs, n_agents, algo and policy all agree.
    assert merged == direct


def test_damaged_finished_cells_are_run_again(tmp_path: Path, monkeypatch, capsys) -> None:
    """A truncated evaluation.json is evaluated again; a changed team zip is kept aside and the
    team retrained (bit for bit, so the table does not change)."""
    experiment = load_tiny(tmp_path)
    first = reproduce(experiment, tmp_path / "out", n_jobs=1, progress=False)
    cells = plan_cells(experiment, tmp_path / "out")
    learned = [Path(c.folder) for c in cells if c.variant["kind"] != "baseline"]
    assert len(learned) >= 2
    evaluation = learned[0] / "evaluation.json"
    evaluation.write_text(evaluation.read_text()[:100])  # truncated
    zipped = learned[1] / "team" / "agent_0.zip"
    damaged = bytearray(zipped.read_bytes())
    damaged[len(damaged) // 2] ^= 0xFF
    zipped.write_bytes(bytes(damaged))
    trained = []
    original = runner_module._train

    def counting_train(cell, variant, folder):
        trained.append(Path(cell.folder))
        return original(cell, variant, folder)

    monkeypatch.setattr(runner_module, "_train", counting_train)
    capsys.readouterr()
    second = reproduce(experiment, tmp_path / "out", n_jobs=1, progress=False)
    err = capsys.readouterr().err
    assert f"{evaluation}: unreadable" in err and f"{zipped}: changed since the cell finished" in err
    assert trained == [learned[1]]  # only the damaged team is trained again
    assert (learned[1] / "team.damaged" / "agent_0.zip").read_bytes() == bytes(damaged)  # kept
    assert first.table == second.table
    from sb3_pm.experiments.integrity import check_done

    assert check_done(learned[0]) is None and check_done(learned[1]) is None


def test_eval_env_kwargs_reach_every_evaluation_and_no_training(tmp_path: Path) -> None:
    # failures.yml fails agent_1 in every evaluated episode; training with failures is refused, so a
    # leak into training would stop the learned cell.
    out = tmp_path / "failures"
    argv = ["reproduce", "failures", "--quick", "--out", str(out), "--jobs", "1", "--no-progress"]
    assert main([*argv, "--variants", "default", "grazing"]) == 0
    for variant in ("default", "grazing"):
        payload = json.loads((out / "cells" / variant / "paper-50" / "seed0" / "evaluation.json").read_text())
        assert all(episode["failed_agents"] == 1 for episode in payload["episodes"])
        assert all(episode["first_failure_step"] == 25 for episode in payload["episodes"])
    assert "avg_uncertainty_after_failure" in (out / "by_graph.md").read_text()


def test_a_baseline_variant_is_evaluated_under_its_own_env_kwargs(tmp_path: Path) -> None:
    # known_map.yml runs local_greedy with the default maps and with known targets, on the same
    # episodes; the recorded config says which, and known targets change what the greedy agents do.
    out = tmp_path / "known_map"
    argv = quick_reproduce("known_map", out)
    assert main([*argv, "--variants", "local_greedy", "local_greedy_known_targets"]) == 0
    payloads = {
        variant: json.loads((out / "cells" / variant / "paper-50" / "seed0" / "evaluation.json").read_text())
        for variant in ("local_greedy", "local_greedy_known_targets")
    }
    assert "target_knowledge" not in payloads["local_greedy"]["config"]["env_kwargs"]
    assert payloads["local_greedy_known_targets"]["config"]["env_kwargs"]["target_knowledge"] == "known"
    scores = {k: [e["avg_uncertainty"] for e in p["episodes"]] for k, p in payloads.items()}
    assert scores["local_greedy"] != scores["local_greedy_known_targets"]


def test_eval_env_kwargs_may_not_redefine_the_experiment(tmp_path: Path) -> None:
    path = tmp_path / "bad.yml"
    path.write_text(
        "graphs: [paper-50]\nseeds: [0]\neval_env_kwargs: {max_cycles: 10}\n"
        "variants: {a: {kind: baseline, policy: random}}\n"
    )
    with pytest.raises(ExperimentError, match=r"eval_env_kwargs must not set \['max_cycles'\]"):
        load_experiment(path)
    path.write_text(
        "graphs: [paper-50]\nseeds: [0]\n"
        "variants: {a: {kind: baseline, policy: random, env_kwargs: {n_agents: 2}}}\n"
    )
    with pytest.raises(ExperimentError, match=r"a baseline's env_kwargs must not set \['n_agents'\]"):
        load_experiment(path)


def test_a_train_env_variant_trains_once_per_seed_and_deploys_on_every_graph(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from sb3_pm.graphs import erdos_renyi, save_graphml

    tiny_experiment(tmp_path)
    save_graphml(erdos_renyi(9, 0.4, n_targets=2, seed=4), tmp_path / "other.graphml")
    size_independent_config(tmp_path)
    (tmp_path / "zero_shot.yml").write_text(
        "name: zs\ngraphs: [tiny.graphml, other.graphml]\nseeds: [0, 1]\nepisodes: 1\nmax_cycles: 20\n"
        "n_agents: 2\nconfig: config.yml\nvariants:\n"
        "  transfer: {train_env: 'family:er', timesteps: 32}\n  random: {kind: baseline, policy: random}\n"
    )
    experiment = load_experiment(tmp_path / "zero_shot.yml")
    experiment = experiment.with_graphs([str(tmp_path / "tiny.graphml"), str(tmp_path / "other.graphml")])
    trained = []
    original = runner_module._train

    def counting_train(cell, variant, folder):
        trained.append((cell.seed, Path(folder).relative_to(tmp_path / "out").as_posix()))
        return original(cell, variant, folder)

    monkeypatch.setattr(runner_module, "_train", counting_train)
    reproduce(experiment, tmp_path / "out", n_jobs=1, progress=False)
    assert sorted(trained) == [
        (0, "trained/transfer/family-er/seed0"),
        (1, "trained/transfer/family-er/seed1"),
    ]
    from sb3_pm.agents.training.team import IndependentPPO

    team = IndependentPPO.load(tmp_path / "out" / "trained" / "transfer" / "family-er" / "seed0" / "team")
    assert team.graph.name == "family:er" and team.num_timesteps == 32  # the variant's own budget
    results = json.loads((tmp_path / "out" / "results.json").read_text())["results"]
    graphs = sorted(r["config"]["graph"] for r in results["transfer"])
    assert graphs == ["other", "other", "tiny", "tiny"]  # every seed's one team on both graphs
    # Resuming trains nothing again.
    trained.clear()
    for cell in plan_cells(experiment, tmp_path / "out"):
        (Path(cell.folder) / "DONE").unlink()
    reproduce(experiment, tmp_path / "out", n_jobs=1, progress=False)
    assert trained == []


def test_a_train_agents_variant_trains_that_team_size_and_deploys_the_experiments(tmp_path: Path) -> None:
    """``train_agents``: one team per seed of that size, deployed with the experiment's n_agents
    (agent_i acting with learner agent_(i mod train_agents))."""
    tiny_experiment(tmp_path)
    size_independent_config(tmp_path)
    (tmp_path / "scaled.yml").write_text(
        "name: scaled\ngraphs: [tiny.graphml]\nseeds: [0]\nepisodes: 1\nmax_cycles: 20\n"
        "n_agents: 3\nconfig: config.yml\nvariants:\n"
        "  small: {train_env: 'family:er', train_agents: 2, timesteps: 32}\n"
    )
    experiment = load_experiment(tmp_path / "scaled.yml").with_graphs([str(tmp_path / "tiny.graphml")])
    (cell,) = plan_cells(experiment, tmp_path / "out")
    assert runner_module.cell_config(cell, runner_module.Variant(**cell.variant)).n_agents == 2
    reproduce(experiment, tmp_path / "out", n_jobs=1, progress=False)
    from sb3_pm.agents.training.team import IndependentPPO

    team = IndependentPPO.load(tmp_path / "out" / "trained" / "small" / "family-er" / "seed0" / "team")
    assert team.n_agents == 2
    (result,) = json.loads((tmp_path / "out" / "results.json").read_text())["results"]["small"]
    assert result["config"]["n_agents"] == 3
    record = runner_module.experiment_record(experiment)  # a changed team size is another experiment
    assert record["variants"]["small"]["train_agents"] == 2


@pytest.mark.parametrize("path", every_experiment_file(), ids=lambda p: p.stem)
def test_every_shipped_experiment_loads_and_plans(path: Path, tmp_path: Path) -> None:
    assert plan_cells(load_experiment(path), tmp_path)


def _variants(name: str) -> dict:
    """The variants of the shipped experiment ``name``, by key."""
    return {v.key: v for v in load_experiment(experiment_file(name)).variants}


def test_one_key_experiments_change_only_what_they_name(tmp_path: Path) -> None:
    variants = _variants("lr_schedule")
    assert variants["linear"].hyperparams == {"learning_rate": "lin_1e-3"}
    assert variants["constant"].hyperparams == {"learning_rate": 0.001}
    budget = load_experiment(experiment_file("budget"))
    variants = _variants("budget")
    assert budget.timesteps == 50000 and variants["budget_50k"].timesteps is None
    assert variants["budget_100k"].timesteps == 100000
    assert not variants["budget_100k"].hyperparams and not variants["budget_100k"].policy_kwargs
    discount = _variants("discount")
    assert discount["gamma_099"].hyperparams == {"gamma": 0.99}  # the default's own value
    assert discount["gamma_0995"].hyperparams == {"gamma": 0.995}
    assert not discount["gamma_0995"].policy_kwargs and discount["gamma_0995"].timesteps is None
    rate = _variants("learning_rate")
    assert rate["lr_1e3"].hyperparams == {"learning_rate": 0.001}  # the default's own value
    assert rate["lr_2e3"].hyperparams == {"learning_rate": 0.002}
    assert rate["lr_5e4"].hyperparams == {"learning_rate": 0.0005}
    updates = _variants("updates")
    assert not updates["default"].hyperparams and not updates["default"].policy_kwargs
    assert updates["rollout_250"].hyperparams == {"n_steps": 125, "batch_size": 125}
    assert updates["minibatch_125"].hyperparams == {"batch_size": 125}
    assert updates["epochs_5"].hyperparams == {"n_epochs": 5}
    assert updates["envs_4"].hyperparams == {"n_envs": 4, "n_steps": 125}  # rollout 4 x 125 = 2 x 250
    epochs = _variants("fewer_epochs")  # the default of its time (zoo/ippo_split.yml), unpinned
    assert epochs["epochs_10"].hyperparams == {"n_epochs": 10}  # the default's own value
    assert epochs["epochs_5"].hyperparams == {"n_epochs": 5}
    assert epochs["epochs_3"].hyperparams == {"n_epochs": 3}
    for variant in (epochs["epochs_10"], epochs["epochs_5"], epochs["epochs_3"]):
        assert not variant.env_kwargs and not variant.policy_kwargs and variant.timesteps is None
    entropy = _variants("entropy")
    assert entropy["ent_001"].hyperparams == {"ent_coef": 0.01}  # the default's own value
    assert entropy["ent_0"].hyperparams == {"ent_coef": 0.0}
    radius = _variants("radius")
    assert radius["radius_1"].env_kwargs == {"obs_radius": 1}  # the default's own value
    assert radius["radius_2"].env_kwargs == {"obs_radius": 2}
    assert not radius["radius_2"].hyperparams and not radius["radius_2"].policy_kwargs
    default_reward = REWARD_BEFORE_TERRITORY  # the default's reward when these were measured
    collision = _variants("collision_reward")["collision_001"]
    assert collision.env_kwargs == {"reward": {**default_reward, "collision": 0.01}}
    assert not collision.hyperparams and not collision.policy_kwargs
    known = _variants("known_map")
    assert known["known_targets"].env_kwargs == {"target_knowledge": "known"}
    assert known["known_map"].env_kwargs == {"target_knowledge": "known", "graph_knowledge": "known"}
    assert known["known_graph"].env_kwargs == {"graph_knowledge": "known"}
    assert not known["known_map"].hyperparams and not known["known_map"].policy_kwargs
    transfer_known = _variants("transfer_known_map")
    # the same map, and ippo_transfer.yml's env of the time pinned (before its territory input)
    before_territory = {
        "territory_input": False,
        "advice_input": False,
        "reward": {"clearing": 0.04, "collision": 0.001},
    }
    assert transfer_known["known_map"].env_kwargs == {**known["known_map"].env_kwargs, **before_territory}
    assert transfer_known["known_map"].config is None
    assert transfer_known["known_map"].policy_kwargs == {"advice_prior": 0.0}  # pinned: no prior


#: The experiment files built on zoo/ippo_transfer_split.yml (zoo/ippo_transfer.yml when they were
#: measured), with the map knowledge, territory
#: settings, the rule's advice (input, and the variants' priors) and deploy filter each measured.
#: The advice columns: the variants with ``advice_input`` on; the priors: each variant's
#: ``advice_prior`` where it is not 0.
AUTO = {"neglect_bound": "auto", "neglect_scope": "territory"}
TRANSFER_EXPERIMENTS = [
    (
        "held_out",
        "known",
        True,
        {
            "transfer_planned",
            "transfer_planned_prior4",
            "transfer_planned_prior8",
            "transfer_planned_prior4_no_rule6",
            "transfer_planned_tours_prior4",
            "transfer_planned_prior4_imitation",
        },
        {
            "transfer_planned": 2.0,
            "transfer_planned_prior4": 4.0,
            "transfer_planned_prior8": 8.0,
            "transfer_planned_prior4_no_rule6": 4.0,
            "transfer_planned_tours_prior4": 4.0,
            "transfer_planned_prior4_imitation": 4.0,
        },
        None,
    ),
    ("zero_shot", "discovered", False, set(), {}, None),
    ("zero_shot_scaling", "discovered", False, set(), {}, None),
    ("transfer_known_map", "known", False, set(), {}, None),
    ("transfer_territory", "known", True, set(), {}, None),
    (
        "regime_100",
        "known",
        True,
        {"transfer_advice", "transfer_family"},
        {"transfer_advice": 2.0, "transfer_family": 2.0},
        None,
    ),
    (
        "regime_200",
        "known",
        True,
        {"transfer_advice", "transfer_family"},
        {"transfer_advice": 2.0, "transfer_family": 2.0},
        None,
    ),
    (
        "transfer_advice",
        "known",
        True,
        {"advice_prior", "advice_prior_family", "advice"},
        {"advice_prior": 2.0, "advice_prior_family": 2.0},
        AUTO,
    ),
]


def _built_on_ippo_transfer(config: object) -> bool:
    names = ("ippo_transfer.yml", "ippo_transfer_prior4.yml", "ippo_transfer_split.yml")
    return config is not None and Path(str(config)).name in names


def test_every_experiment_built_on_ippo_transfer_is_checked_for_what_it_measured() -> None:
    """A new file that trains a transfer config must join TRANSFER_EXPERIMENTS (and so pin
    the settings it measures), or a change of the config would change what it measures."""
    built_on = set()
    for path in every_experiment_file():
        experiment = load_experiment(path)
        configs = [experiment.config, *(variant.config for variant in experiment.variants)]
        if any(_built_on_ippo_transfer(config) for config in configs):
            built_on.add(path.stem)
    assert built_on == {name for name, *_ in TRANSFER_EXPERIMENTS}


@pytest.mark.parametrize(
    ("name", "knowledge", "territory", "advice", "priors", "deploy"), TRANSFER_EXPERIMENTS
)
def test_the_transfer_experiments_train_under_the_env_settings_they_measured(
    tmp_path: Path,
    name: str,
    knowledge: str,
    territory: bool,
    advice: set[str],
    priors: dict[str, float],
    deploy: dict | None,
) -> None:
    """zoo/ippo_transfer_split.yml gives a known map, the territory input and reward, the rule's
    advice with a prior, and the calibrated bound; the files that measured other settings pin them, so
    every variant built on it trains (and, keeping its env settings, deploys) as measured."""
    experiment = load_experiment(experiment_file(name))
    learned = 0
    for cell in plan_cells(experiment, tmp_path):
        if cell.variant["kind"] == "baseline" or not _built_on_ippo_transfer(
            cell.variant["config"] or cell.config
        ):
            continue
        config = runner_module.cell_config(cell, runner_module.Variant(**cell.variant))
        where = (name, cell.variant["key"])
        for key in ("target_knowledge", "graph_knowledge"):  # unset: the env's default, discovered
            assert config.env_kwargs.get(key, "discovered") == knowledge, (*where, key)
        assert config.env_kwargs.get("territory_input", False) is territory, where
        assert config.env_kwargs.get("advice_input", False) is (cell.variant["key"] in advice), where
        prior = config.hyperparams["policy_kwargs"].get("advice_prior", 0.0)
        assert prior == priors.get(cell.variant["key"], 0.0), where
        assert "advice_prior" in cell.variant["policy_kwargs"], where  # pinned, not the config's
        # The graph it trains on is pinned too: without train_env the runner would train one team
        # per graph of the file, not the shared team these files measured zero-shot.
        assert cell.variant["train_env"] is not None, where
        assert config.deploy_filter == deploy, where
        assert ("territory" in config.env_kwargs["reward"]) is territory, where
        learned += 1
    assert learned > 0


def test_a_variant_sets_per_agent_overrides_validated_like_the_config_files_own(tmp_path: Path) -> None:
    """``agents:`` in a variant reaches the training config as the file's own ``agents`` key would,
    and a name outside the team or a team-wide key fails with the loader's one-line error."""
    from sb3_pm.zoo.config import ConfigError

    tiny_experiment(tmp_path)

    def config_of(agents: str):
        (tmp_path / "per_agent.yml").write_text(
            "name: per_agent\ngraphs: [tiny.graphml]\nseeds: [0]\nepisodes: 1\nmax_cycles: 20\n"
            f"n_agents: 2\nconfig: config.yml\nvariants:\n  staggered: {{agents: {agents}}}\n"
        )
        experiment = load_experiment(tmp_path / "per_agent.yml")
        experiment = experiment.with_graphs([str(tmp_path / "tiny.graphml")])
        (cell,) = [c for c in plan_cells(experiment, tmp_path / "out") if c.variant["key"] == "staggered"]
        return runner_module.cell_config(cell, runner_module.Variant(**cell.variant))

    config = config_of("{agent_1: {learning_rate: 0.0007}}")
    assert config.agents == {"agent_1": {"learning_rate": 0.0007}}
    assert "learning_rate" not in config.hyperparams  # the rest of the team keeps the file's
    with pytest.raises(ExperimentError, match=r"unknown agent 'agent_2' \(the team has agent_0 .. agent_1\)"):
        config_of("{agent_2: {learning_rate: 0.0007}}")  # at load, before any cell trains
    with pytest.raises(ConfigError, match=r"'n_envs' is set for the whole team, not per agent"):
        config_of("{agent_0: {n_envs: 2}}")
    with pytest.raises(ExperimentError, match=r"agents.agent_0 must be a mapping of hyperparameters"):
        config_of("{agent_0: 0.0007}")
    (tmp_path / "bad.yml").write_text(
        "graphs: [paper-50]\nseeds: [0]\n"
        "variants: {a: {kind: baseline, policy: random, agents: {agent_0: {learning_rate: 0.1}}}}\n"
    )
    with pytest.raises(ExperimentError, match=r"'agents' applies to independent variants only"):
        load_experiment(tmp_path / "bad.yml")


#: The experiment that measures the default as it is now, for the README's headline table.
HEADLINE = "headline"
#: The default before planned territories became paper-50's: the files measured on it train it by
#: name (zoo/ippo_split.yml), so a change of zoo/ippo.yml leaves their cells as recorded.
SPLIT_DEFAULT = "ippo_split"
#: Files that measure a default unpinned, by the config they train: the headline today's, and
#: variants of the default of their time that change only the keys they name.
CURRENT_DEFAULT_FILES = {HEADLINE: "ippo", "fewer_epochs": SPLIT_DEFAULT}
#: Files measured on the default of its time with the topology known and staggered rates, before
#: the territory reward: they pin only the reward.
STAGGERED_DEFAULT_FILES = ("territory_reward",)
#: Files that vary the default of their time (zoo/ippo_split.yml): their variants name env settings
#: on top of it, nothing pinned.
VARIES_THE_SPLIT_DEFAULT_FILES = ("planned_territories",)
PREVIOUS_DEFAULT_FILES = sorted(
    path.stem
    for path in every_experiment_file()
    if (trains_the_default(path) or trains_the_split_default(path))
    and path.stem not in CURRENT_DEFAULT_FILES
    and path.stem not in STAGGERED_DEFAULT_FILES
    and path.stem not in VARIES_THE_SPLIT_DEFAULT_FILES
)
REWARD_BEFORE_TERRITORY = {"clearing": 0.04, "collision": 0.001}
#: The default's passes over each rollout before n_epochs 5: every file measured before pins it.
EPOCHS_BEFORE = 10


@pytest.mark.parametrize(("name", "base"), CURRENT_DEFAULT_FILES.items())
def test_the_headline_experiment_measures_the_default_unpinned(tmp_path: Path, name: str, base: str) -> None:
    """The headline's cells are today's default's; a file that varies the default of its time
    changes only the hyperparameters its variants name."""
    experiment = load_experiment(experiment_file(name))
    assert experiment.config is not None and experiment.config.name == f"{base}.yml"
    assert not experiment.env_kwargs and not experiment.hyperparams
    default = load_config(base, "paper-50")
    learned = [cell for cell in plan_cells(experiment, tmp_path) if cell.variant["kind"] != "baseline"]
    assert learned
    for cell in learned:
        config = runner_module.cell_config(cell, runner_module.Variant(**cell.variant))
        expected = {**default.team_kwargs(), "env_kwargs": config.env_kwargs}
        expected["hyperparams"] = {**expected["hyperparams"], **cell.variant["hyperparams"]}
        assert config.team_kwargs() == expected
        assert config.env_kwargs == default.env_kwargs


@pytest.mark.parametrize("name", VARIES_THE_SPLIT_DEFAULT_FILES)
def test_a_file_that_varies_the_split_default_changes_only_what_its_variants_name(
    tmp_path: Path, name: str
) -> None:
    experiment = load_experiment(experiment_file(name))
    assert trains_the_split_default(experiment_file(name))
    assert not experiment.env_kwargs and not experiment.hyperparams
    default = load_config(SPLIT_DEFAULT, "paper-50")
    learned = [cell for cell in plan_cells(experiment, tmp_path) if cell.variant["kind"] != "baseline"]
    assert learned
    for cell in learned:
        config = runner_module.cell_config(cell, runner_module.Variant(**cell.variant))
        expected = {
            **default.team_kwargs(),
            "env_kwargs": {**default.env_kwargs, **cell.variant["env_kwargs"]},
        }
        named = dict(cell.variant["hyperparams"])
        expected["deploy_filter"] = named.pop("deploy_filter", expected["deploy_filter"])  # a team key
        expected["hyperparams"] = {**expected["hyperparams"], **named}
        policy_kwargs = {**expected["hyperparams"]["policy_kwargs"], **cell.variant["policy_kwargs"]}
        expected["hyperparams"]["policy_kwargs"] = policy_kwargs
        assert config.team_kwargs() == expected


@pytest.mark.parametrize("quick", [False, True])
@pytest.mark.parametrize("name", PREVIOUS_DEFAULT_FILES)
def test_experiments_measured_on_the_previous_default_train_as_they_were_measured(
    tmp_path: Path, name: str, quick: bool
) -> None:
    """zoo/ippo.yml and zoo/ippo_split.yml know the road network and stagger the learning rates;
    the files measured before pin the topology discovered and one learning rate, so their learned
    variants train as recorded unless a variant sets ``known`` itself (and baselines, which read the
    same maps, are evaluated on discovered maps too). ``--quick`` keeps the pins: its hyperparams
    merge over the file's."""
    experiment = load_experiment(experiment_file(name))
    assert experiment.env_kwargs.get("graph_knowledge") == "discovered", name
    assert experiment.hyperparams["n_epochs"] == EPOCHS_BEFORE, name
    if quick:
        experiment = experiment.quick()
    pinned = experiment.hyperparams  # the file's pins, with --quick's budget over them
    for cell in plan_cells(experiment, tmp_path):
        own = cell.variant["env_kwargs"].get("graph_knowledge", "discovered")
        if cell.variant["kind"] == "baseline":
            assert {**cell.env_kwargs, **cell.variant["env_kwargs"]}["graph_knowledge"] == own
            continue
        config = runner_module.cell_config(cell, runner_module.Variant(**cell.variant))
        assert config.env_kwargs["graph_knowledge"] == own, (name, cell.variant["key"])
        # one learning rate for every learner, as when they were measured, unless the variant sets
        # its own spread (an agents block, as in staggered_lr.yml, is written out in full)
        own_spread = cell.variant["hyperparams"].get("learning_rate_spread", 1.0)
        assert config.learning_rate_spread == own_spread, (name, cell.variant["key"])
        # and no territory reward, unless the variant sets its own reward
        own_reward = cell.variant["env_kwargs"].get("reward", REWARD_BEFORE_TERRITORY)
        assert config.env_kwargs["reward"] == own_reward, (name, cell.variant["key"])
        # and acting under the filter they trained under, not paper-50's deploy bound
        assert config.deploy_filter is None, (name, cell.variant["key"])
        # and with the passes over each rollout of their time (--quick's own win where it sets them)
        own_epochs = {**pinned, **cell.variant["hyperparams"]}.get("n_epochs", EPOCHS_BEFORE)
        assert config.hyperparams["n_epochs"] == own_epochs, (name, cell.variant["key"])


def test_quick_budget_keys_win_over_a_variants_own(tmp_path: Path) -> None:
    """``--quick``'s rollout size and epochs replace a variant's, as its timesteps do, so a smoke test
    stays small; the variant's other keys (its pins) hold. comparison.yml's ``default`` row pins
    ``n_epochs: 10`` and ``learning_rate_spread: 1`` in the variant itself."""
    experiment = load_experiment("comparison")
    full = {c.variant["key"]: c for c in plan_cells(experiment, tmp_path / "full")}
    quick = {c.variant["key"]: c for c in plan_cells(experiment.quick(), tmp_path / "quick")}
    assert full["default"].variant["hyperparams"]["n_epochs"] == EPOCHS_BEFORE
    config = runner_module.cell_config(quick["default"], runner_module.Variant(**quick["default"].variant))
    assert config.hyperparams["n_epochs"] == 1 and config.hyperparams["n_steps"] == 50
    assert config.learning_rate_spread == 1.0 and config.deploy_filter is None


@pytest.mark.parametrize("name", STAGGERED_DEFAULT_FILES)
def test_experiments_measured_on_the_staggered_default_pin_its_reward(tmp_path: Path, name: str) -> None:
    """Files measured against the default before the territory reward train that default as their
    ``default`` variant: the topology known, staggered rates, the reward without the term."""
    experiment = load_experiment(experiment_file(name))
    assert trains_the_split_default(experiment_file(name))
    became = load_config(SPLIT_DEFAULT, "paper-50")  # the default that the territory variant became
    cells = {cell.variant["key"]: cell for cell in plan_cells(experiment, tmp_path)}
    config = runner_module.cell_config(cells["default"], runner_module.Variant(**cells["default"].variant))
    assert config.env_kwargs["reward"] == REWARD_BEFORE_TERRITORY
    assert config.env_kwargs["graph_knowledge"] == "known" and config.learning_rate_spread == 2.0
    territory = cells["territory"]
    config = runner_module.cell_config(territory, runner_module.Variant(**territory.variant))
    # the variant that became the default, measured before paper-50's deploy bound and with the
    # passes over each rollout of its time
    expected = {**became.team_kwargs(), "env_kwargs": config.env_kwargs, "deploy_filter": None}
    expected["hyperparams"] = {**expected["hyperparams"], "n_epochs": EPOCHS_BEFORE}
    assert config.team_kwargs() == expected
    assert became.hyperparams["n_epochs"] != EPOCHS_BEFORE
    assert config.env_kwargs == became.env_kwargs
    assert config.deploy_filter is None and became.deploy_filter is not None


def _learned_cells(tmp_path: Path, name: str, key: str) -> dict[int, tuple[Any, ...]]:
    """The cells of variant ``key`` of experiment ``name``, by seed: what each trains and where it
    is evaluated (graph, episodes, steps, team size, budget and the training config's team keys)."""
    experiment = load_experiment(experiment_file(name))
    cells = [c for c in plan_cells(experiment, tmp_path / name) if c.variant["key"] == key]
    assert cells
    rows = {}
    for cell in cells:
        variant = runner_module.Variant(**cell.variant)
        config = runner_module.cell_config(cell, variant)
        budget = variant.timesteps or cell.timesteps or config.n_timesteps
        training = (variant.kind, variant.train, variant.train_env, variant.train_agents, budget)
        evaluation = (cell.graph, cell.episodes, cell.max_cycles, cell.n_agents, cell.eval_env_kwargs)
        rows[cell.seed] = (*training, *evaluation, config.team_kwargs())
    return rows


def test_the_headline_default_trains_the_planned_prior_teams(tmp_path: Path) -> None:
    """paper-50's default is planned_territories.yml's ``planned_prior`` team: the headline's
    ``default`` cells train it on the same graph, seeds and episodes, and differ only in how the
    trained team acts: the default's deploy filter (paper-50's neglect bound) and temperature,
    where planned_prior was measured without a filter, by its most likely actions."""
    headline = _learned_cells(tmp_path, HEADLINE, "default")
    planned = _learned_cells(tmp_path, "planned_territories", "planned_prior")
    assert planned.keys() <= headline.keys()
    for seed, row in planned.items():
        *where, team = row
        *headline_where, headline_team = headline[seed]
        assert where == headline_where, seed
        assert team.pop("deploy_filter") is None
        assert headline_team.pop("deploy_filter") == load_config("ippo", "paper-50").deploy_filter
        assert team.pop("deploy_temperature") is None
        assert headline_team.pop("deploy_temperature") == load_config("ippo", "paper-50").deploy_temperature
        assert team == headline_team, seed  # every other key, the learners' own included


def test_the_split_default_is_the_fewer_epochs_variant_that_became_it(tmp_path: Path) -> None:
    """The default before planned territories (zoo/ippo_split.yml) is fewer_epochs.yml's
    ``epochs_5`` team: its cells train that config as it is, n_epochs included."""
    split = load_config(SPLIT_DEFAULT, "paper-50")
    assert split.hyperparams["n_epochs"] == 5
    for row in _learned_cells(tmp_path, "fewer_epochs", "epochs_5").values():
        assert row[-1] == split.team_kwargs()


@pytest.mark.parametrize("name", CURRENT_DEFAULT_FILES)
def test_the_headline_default_acts_under_the_territory_bound(tmp_path: Path, name: str) -> None:
    """The headline measures the default as a user gets it (and fewer_epochs the default of its
    time): trained unfiltered, acting under paper-50's deploy filter (the neglect bound on each
    agent's own territory; the headline's default also with the filter's rule 9)."""
    expected: dict[str, object] = {"neglect_bound": 50.0, "neglect_scope": "territory"}
    if name == HEADLINE:
        expected["leave_cleared"] = True
    cells = [
        c
        for c in plan_cells(load_experiment(experiment_file(name)), tmp_path)
        if c.variant["kind"] != "baseline"
    ]
    assert cells
    for cell in cells:
        config = runner_module.cell_config(cell, runner_module.Variant(**cell.variant))
        assert config.deploy_filter == expected


#: The graphs whose zoo/ippo.yml entry plays planned territories, and the one file that trains them.
PLANNED_DEFAULT_GRAPHS = {
    "paper-50": HEADLINE,
    "paper_50n_8t": HEADLINE,
    "rgg-60": None,
    "rooms-4": None,
    "cliques-6x8": None,
}


def test_the_planned_default_graphs_are_those_of_zoo_ippo() -> None:
    for graph in [*PLANNED_DEFAULT_GRAPHS, "paper-100", "karate"]:
        planned = load_config("ippo", graph).env_kwargs.get("territories") == "planned"
        assert planned == (graph in PLANNED_DEFAULT_GRAPHS), graph


@pytest.mark.parametrize("path", every_experiment_file(), ids=lambda p: p.stem)
def test_only_the_headline_trains_todays_planned_defaults(path: Path, tmp_path: Path) -> None:
    """Every learned cell that trains a planned-territory entry of zoo/ippo.yml is the headline's
    (paper-50): the other files were measured on an earlier default and train it by name
    (zoo/ippo_split.yml), so that the next change of the default leaves their cells as recorded.
    Files on zoo/ippo.yml whose learned cells are on other graphs only (regime_100.yml ...) may
    stay on it."""
    experiment = load_experiment(path)
    on_default = []
    for run in (experiment, experiment.quick()):
        for cell in plan_cells(run, tmp_path):
            config = cell.variant["config"] or cell.config
            if cell.variant["kind"] == "baseline" or config is None:
                continue
            if Path(str(config)).name == "ippo.yml" and str(cell.graph) in PLANNED_DEFAULT_GRAPHS:
                if PLANNED_DEFAULT_GRAPHS[str(cell.graph)] != path.stem:
                    on_default.append((cell.variant["key"], cell.graph))
    assert not on_default, on_default


def test_the_family_defaults_are_the_families_planned_prior_teams(tmp_path: Path) -> None:
    """zoo/ippo.yml's entries for rgg-60, rooms-4 and cliques-6x8 are families.yml's
    ``planned_prior`` team, written out there on top of the split default it was measured on;
    cliques-6x8 deploys it with paper-50's neglect bound, and rgg-60 under the filter's rule 12,
    as each was measured there."""
    experiment = load_experiment(experiment_file("families"))
    checked = set()
    for cell in plan_cells(experiment, tmp_path):
        if cell.variant["key"] != "planned_prior" or str(cell.graph) not in PLANNED_DEFAULT_GRAPHS:
            continue
        measured = runner_module.cell_config(cell, runner_module.Variant(**cell.variant)).team_kwargs()
        default = load_config("ippo", str(cell.graph)).team_kwargs()
        if cell.graph == "cliques-6x8":
            assert default.pop("deploy_filter") == load_config("ippo", "paper-50").deploy_filter
            assert measured.pop("deploy_filter") is None
        if cell.graph == "rgg-60":
            assert default.pop("deploy_filter") == {
                "neglect_bound": None,
                "neglect_scope": "known",
                "visit_deadline": "auto",
            }
            assert measured.pop("deploy_filter") is None
        assert measured == default, cell.graph
        checked.add(str(cell.graph))
    assert checked == {"rgg-60", "rooms-4", "cliques-6x8"}


def test_the_default_config_knows_the_road_network() -> None:
    assert load_config("ippo", "paper-50").env_kwargs["graph_knowledge"] == "known"


def test_a_variant_pins_the_learning_rate_spread_as_a_team_key(tmp_path: Path) -> None:
    """``hyperparams: {learning_rate_spread: ...}`` sets the team's spread; it never reaches the
    algorithm, and a bad value fails when the file is read."""
    (tmp_path / "spread.yml").write_text(
        "graphs: [paper-50]\nseeds: [0]\nconfig: " + str(ZOO / "ippo.yml") + "\n"
        "variants:\n  flat: {hyperparams: {learning_rate_spread: 1}}\n  default: {}\n"
    )
    experiment = load_experiment(tmp_path / "spread.yml")
    spreads = {}
    for cell in plan_cells(experiment, tmp_path):
        config = runner_module.cell_config(cell, runner_module.Variant(**cell.variant))
        assert "learning_rate_spread" not in config.hyperparams
        spreads[cell.variant["key"]] = config.learning_rate_spread
    assert spreads == {"flat": 1.0, "default": 2.0}
    (tmp_path / "bad.yml").write_text(
        "graphs: [paper-50]\nseeds: [0]\nconfig: " + str(ZOO / "ippo.yml") + "\n"
        "variants:\n  wide: {hyperparams: {learning_rate_spread: -2}}\n"
    )
    with pytest.raises(ExperimentError, match=r"'wide': hyperparams.learning_rate_spread: expected"):
        load_experiment(tmp_path / "bad.yml")


def test_the_spread_is_recorded_and_a_centralized_variant_with_one_fails_before_training(
    tmp_path: Path,
) -> None:
    (tmp_path / "spread.yml").write_text(
        "graphs: [paper-50]\nseeds: [0]\nconfig: " + str(ZOO / "ippo.yml") + "\n"
        "variants:\n  flat: {hyperparams: {learning_rate_spread: 1}}\n  default: {}\n"
    )
    record = runner_module.experiment_record(load_experiment(tmp_path / "spread.yml"))
    assert record["learning_rate_spread"] == {"default": 2.0}  # an edited default is another experiment
    (tmp_path / "central.yml").write_text(
        "graphs: [paper-50]\nseeds: [0]\nconfig: " + str(ZOO / "ippo.yml") + "\n"
        "variants:\n  central: {kind: centralized}\n"
    )
    with pytest.raises(ExperimentError, match=r"'central': a centralized team has one learning rate"):
        reproduce(load_experiment(tmp_path / "central.yml"), tmp_path / "out", progress=False)
    assert not (tmp_path / "out" / "cells").exists()


ALL_BUT_CURRENT_DEFAULT_FILES = sorted(
    path.stem for path in every_experiment_file() if path.stem not in CURRENT_DEFAULT_FILES
)


@pytest.mark.parametrize("name", ALL_BUT_CURRENT_DEFAULT_FILES)
def test_only_the_headline_acts_under_paper_50s_deploy_filter(tmp_path: Path, name: str) -> None:
    """Every file but those of today's default was measured before the default's deploy filter: its
    learned cells, whatever config a variant names, act under the filter they trained under."""
    experiment = load_experiment(experiment_file(name))
    for cell in plan_cells(experiment, tmp_path):
        if cell.variant["kind"] == "baseline" or not (cell.variant.get("config") or cell.config):
            continue
        config = runner_module.cell_config(cell, runner_module.Variant(**cell.variant))
        # transfer_advice was measured under the site's calibrated bound (auto), as it ships
        measured = AUTO if name == "transfer_advice" else None
        assert config.deploy_filter == measured, (name, cell.variant["key"], cell.graph)


def test_the_report_names_a_variants_own_training_budget(tmp_path: Path) -> None:
    from sb3_pm.experiments.report import write_report

    for name in ("results.md", "anova.txt", "by_graph.md", "effects.md", "runs.md"):
        (tmp_path / name).write_text("x\n")
    (tmp_path / "command.txt").write_text("sb3-pm reproduce e\n")
    record = {
        "name": "e",
        "graphs": ["paper-50"],
        "seeds": [0],
        "episodes": 1,
        "max_cycles": 10,
        "n_agents": 4,
        "evaluation_seeds": "1000000 + seed * 1000 + episode",
        "timesteps": 50000,
        "variants": {"long": {"kind": "independent", "timesteps": 150000}, "grazing": {"kind": "baseline"}},
    }
    report = write_report(tmp_path, record, [], reference="x").read_text()
    assert "50000 steps per learner" in report
    assert "variant `long`: 150000 steps per learner" in report and "`grazing`" not in report


def test_jobs_side_by_side_share_the_cores_between_their_teams(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Each local job's team gets the cores over the jobs running at once as its update slots."""
    from sb3_pm.agents.multiplexing import update_slots
    from sb3_pm.experiments import runner

    experiment = load_tiny(tmp_path)
    monkeypatch.setattr(runner, "usable_cores", lambda: 10)  # not this machine's count
    planned: list = []

    class Planned(Exception):
        pass

    def plan_only(function, jobs, **kwargs):
        planned.extend(jobs)
        raise Planned

    with monkeypatch.context() as patch:
        patch.setattr(runner, "run_jobs", plan_only)
        with pytest.raises(Planned):
            reproduce(experiment, tmp_path / "four", n_jobs=4, progress=False)
    # 10 cores, 4 jobs; two of the four cells train (the random baseline's two do not)
    assert len(planned) == 4 and {cell.update_slots for cell in planned} == {5}

    counts: list[int] = []
    original = update_slots.UpdateSlots.__init__

    def recorded(self, count: int) -> None:
        counts.append(count)
        original(self, count)

    monkeypatch.setattr(update_slots.UpdateSlots, "__init__", recorded)
    reproduce(experiment, tmp_path / "one", n_jobs=1, progress=False)  # in this process
    assert counts == [10, 10]  # one job at a time: every core; one learn() per learned cell


@pytest.mark.parametrize(
    ("name", "variant"),
    [
        ("transfer_advice", "advice_prior_family"),
        ("regime_100", "transfer_family"),
        ("regime_200", "transfer_family"),
    ],
)
def test_the_shipped_transfer_team_rows_train_on_the_config_family(name: str, variant: str) -> None:
    """The rows that measure zoo/ippo_transfer_split.yml train where the config does (family:er),
    and the rows of the team before it on paper-50."""
    from sb3_pm.zoo.config import default_env

    variants = {v.key: v for v in load_experiment(experiment_file(name)).variants}
    assert str(variants[variant].train_env) == default_env("ippo_transfer_split") == "family:er"
    before = "advice_prior" if name == "transfer_advice" else "transfer_advice"
    assert str(variants[before].train_env) == "paper-50"
