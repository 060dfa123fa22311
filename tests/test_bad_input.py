"""Every bad value is refused with one line that names it, before any folder is created.

Each case below once gave a traceback (a NaN-logits one after a whole rollout, leaving a run folder
with no team) or was accepted silently.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import yaml

from sb3_pm.cli import main
from sb3_pm.zoo import load_config
from sb3_pm.zoo.checks import ConfigError


def one_line_error(capsys: pytest.CaptureFixture[str], *names: str) -> str:
    """The command's error, checked to be one line naming each of ``names``."""
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert "Traceback" not in err
    for name in names:
        assert name in err, (name, err)
    return err


#: (key, value as YAML writes it) of config values that must be refused.
BAD_CONFIG_VALUES = [
    ("learning_rate", ".nan"),
    ("learning_rate", "-1"),
    ("learning_rate", "lin_nan"),
    ("learning_rate", "lin_-1"),
    ("learning_rate", ".inf"),
    ("gamma", "1.5"),
    ("ent_coef", ".nan"),
    ("gae_lambda", ".nan"),
    ("n_steps", "1"),
    ("clip_range", ".nan"),
    ("max_grad_norm", ".inf"),
    ("batch_size", "17"),  # the rollout is n_steps 16 x n_envs 1
]


@pytest.mark.parametrize(("key", "value"), BAD_CONFIG_VALUES)
def test_train_refuses_a_bad_config_value_before_the_run_folder(tiny_train, capsys, key, value) -> None:
    config, graph, out = tiny_train
    config.write_text(config.read_text() + f"  {key}: {value}\n")
    argv = ["train", "--config", str(config), "--env", str(graph), "--out", str(out), "--no-progress"]
    assert main(argv) == 2
    one_line_error(capsys, f"default.{key}")
    assert not out.exists()
    with pytest.raises(ConfigError, match=key):
        load_config(config, str(graph))


@pytest.mark.parametrize(("key", "value"), BAD_CONFIG_VALUES)
def test_train_refuses_a_bad_override_before_the_run_folder(tiny_train, capsys, key, value) -> None:
    config, graph, out = tiny_train
    argv = ["train", "--config", str(config), "--env", str(graph), "--out", str(out), "--no-progress"]
    assert main([*argv, "--hyperparams", f"{key}:{value}"]) == 2
    one_line_error(capsys, f".{key}")
    assert not out.exists()


def test_batch_size_is_checked_against_the_rollout_n_envs_makes(tiny_train, capsys) -> None:
    """``--n-envs`` shrinks the rollout after the config was read: batch_size is checked again."""
    config, graph, out = tiny_train
    config.write_text(
        config.read_text().replace("n_envs: 1", "n_envs: 2").replace("batch_size: 16", "batch_size: 32")
    )
    load_config(config, str(graph))  # 32 <= 16 x 2
    argv = ["train", "--config", str(config), "--env", str(graph), "--out", str(out), "--n-envs", "1"]
    assert main(argv) == 2
    one_line_error(capsys, "batch_size", "--n-envs")
    assert not out.exists()


def test_max_cycles_written_1e7_must_be_an_integer(tiny_train, capsys) -> None:
    """YAML reads ``1e7`` as a string; it once reached the env and failed comparing str with int."""
    config, graph, out = tiny_train
    config.write_text(config.read_text().replace("max_cycles: 10", "max_cycles: 1e7"))
    argv = ["train", "--config", str(config), "--env", str(graph), "--out", str(out), "--no-progress"]
    assert main(argv) == 2
    assert "max_cycles: expected an integer" in one_line_error(capsys, "env_kwargs.max_cycles")
    assert not out.exists()


def test_evaluate_and_compare_refuse_a_negative_seed(tmp_path, capsys) -> None:
    argv = ["evaluate", "--policy", "random", "--graph", "karate", "--steps", "3", "--episodes", "1"]
    assert main([*argv, "--seed", "-1"]) == 2
    one_line_error(capsys, "--seed")
    out = tmp_path / "cmp"
    argv = ["compare", "--policies", "random", "--graphs", "karate", "--steps", "3", "--episodes", "1"]
    assert main([*argv, "--seeds", "0", "-1", "--out", str(out)]) == 2
    one_line_error(capsys, "--seeds")
    assert not out.exists()


def test_a_device_this_host_lacks_is_refused(tiny_train, capsys) -> None:
    import torch

    if torch.cuda.is_available():
        pytest.skip("this host has a CUDA GPU")
    config, graph, out = tiny_train
    argv = ["train", "--config", str(config), "--env", str(graph), "--out", str(out), "--device", "cuda"]
    assert main(argv) == 2
    one_line_error(capsys, "--device cuda")
    assert not out.exists()
    assert main(["evaluate", "--policy", "random", "--graph", "karate", "--device", "cuda"]) == 2
    one_line_error(capsys, "--device cuda")
    assert main(["evaluate", "--policy", "random", "--graph", "karate", "--device", "gpu0"]) == 2
    one_line_error(capsys, "--device")


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [("threads", 0, "threads must be an integer of at least 1"), ("device", "cuda", "device")],
)
def test_resume_refuses_a_bad_args_record(tmp_path, capsys, field, value, message) -> None:
    import torch

    if field == "device" and torch.cuda.is_available():
        pytest.skip("this host has a CUDA GPU")
    run = tmp_path / "run"
    run.mkdir()
    (run / "args.yml").write_text(yaml.safe_dump({"threads": 1, "device": "cpu", field: value}))
    assert main(["train", "--resume", str(run)]) == 2
    one_line_error(capsys, "args.yml", message)
    assert sorted(path.name for path in run.iterdir()) == ["args.yml"]


def test_a_manifest_field_of_the_wrong_type_is_one_line(tiny_train, tmp_path, capsys) -> None:
    config, graph, out = tiny_train
    argv = ["train", "--config", str(config), "--env", str(graph), "--out", str(out), "--timesteps", "16"]
    assert main([*argv, "--no-progress"]) == 0
    for field, value in (("graph", "karate"), ("n_agents", "2"), ("agents", {"agent_0": 1})):
        team = tmp_path / f"team_{field}"
        shutil.copytree(out / "team", team)
        manifest = json.loads((team / "manifest.json").read_text())
        manifest[field] = value
        (team / "manifest.json").write_text(json.dumps(manifest))
        capsys.readouterr()
        assert main(["evaluate", "--policy", str(team), "--steps", "3", "--episodes", "1"]) == 2
        one_line_error(capsys, f"field {field} must be")
    from sb3_pm.agents.deployment.saved_teams import read_manifest
    from sb3_pm.errors import InputError

    team = Path(tmp_path / "team_graph")
    with pytest.raises(InputError, match="field graph must be an object"):
        read_manifest(team)


@pytest.mark.parametrize(
    ("settings", "message"),
    [
        ("max_cycles: 1e7\n", "max_cycles: expected an integer >= 1, got '1e7'"),
        ("env_kwargs: {max_cycles: 1e7}\n", "env_kwargs must not set ['max_cycles']"),
        (
            "variants: {learned: {env_kwargs: {max_cycles: 7}}}\n",
            "variant 'learned': env_kwargs must not set",
        ),
    ],
)
def test_an_experiment_refuses_max_cycles_it_would_ignore_or_misread(
    tmp_path, capsys, settings, message
) -> None:
    """An experiment's max_cycles is every cell's: one written in env_kwargs was replaced silently."""
    from tests.test_experiments import tiny_experiment

    path = tiny_experiment(tmp_path)
    text = path.read_text()
    if settings.startswith("variants"):
        text = text.replace("  learned: {}\n", "  learned: {env_kwargs: {max_cycles: 7}}\n")
    else:
        text = text.replace("max_cycles: 20\n", "") + settings
    path.write_text(text)
    out = tmp_path / "out"
    argv = [
        "reproduce",
        str(path),
        "--out",
        str(out),
        "--graphs",
        str(tmp_path / "tiny.graphml"),
        "--jobs",
        "1",
    ]
    assert main(argv) == 2
    one_line_error(capsys, message)
    assert not out.exists()
