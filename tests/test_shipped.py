"""The package stands alone: its configs, experiment files and published graphs ship inside it,
resolve by name from any folder, and the default training config is the best measured one."""

from __future__ import annotations

import configparser
import fnmatch
import subprocess
from pathlib import Path

import pytest
import torch as th
import yaml

from sb3_pm.cli import main
from sb3_pm.experiments import load_experiment
from sb3_pm.graphs.presets import DATA_DIR, PUBLISHED
from sb3_pm.zoo import DEFAULT_CONFIG, load_config, resolve_config_path, resolve_experiment_path
from sb3_pm.zoo.shipped import CONFIG_DIR, EXPERIMENT_DIR

th.set_num_threads(1)

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "sb3_pm"


def _setup_cfg() -> configparser.ConfigParser:
    parser = configparser.ConfigParser()
    parser.read(ROOT / "setup.cfg")
    return parser


def _lines(value: str) -> list[str]:
    return [line.strip() for line in value.splitlines() if line.strip()]


def test_the_shipped_config_folder_is_the_repository_zoo_folder() -> None:
    assert CONFIG_DIR.resolve() == (ROOT / "zoo").resolve()
    shipped = {path.name for path in CONFIG_DIR.glob("*.yml")}
    assert shipped >= {"ippo.yml", "ippo_split.yml", "ippo_paper.yml"}


def test_package_data_covers_every_config_experiment_and_graph() -> None:
    """What a wheel holds is what setup.cfg's package_data globs match: zoo/ installs as the
    package sb3_pm.configs (package_dir), the graphs under sb3_pm/."""
    cfg = _setup_cfg()
    mapping = dict(line.split(" = ") for line in _lines(cfg["options"]["package_dir"]))
    assert mapping == {"sb3_pm.configs": "zoo", "sb3_pm.configs.experiments": "zoo/experiments"}
    data = cfg["options.package_data"]
    folders = {"sb3_pm.configs": CONFIG_DIR, "sb3_pm.configs.experiments": EXPERIMENT_DIR, "sb3_pm": PACKAGE}
    shipped = [*CONFIG_DIR.glob("*.yml"), *EXPERIMENT_DIR.glob("*.yml"), *DATA_DIR.glob("*.graphml")]
    assert len(shipped) >= 3 + 2 + 6
    for path in shipped:
        package = next((name for name, folder in folders.items() if path.parent == folder), "sb3_pm")
        relative = path.relative_to(folders[package]).as_posix()
        assert any(fnmatch.fnmatch(relative, pattern) for pattern in _lines(data[package])), relative
    assert {DATA_DIR / name for name in PUBLISHED.values()} <= set(DATA_DIR.glob("*.graphml"))
    assert "py.typed" in _lines(data["sb3_pm"]) and (PACKAGE / "py.typed").is_file()


def test_setup_cfg_lists_every_package() -> None:
    """setup.cfg lists the packages (one of them is zoo/): a new subpackage must join the list."""
    from setuptools import find_packages

    listed = set(_lines(_setup_cfg()["options"]["packages"]))
    found = set(find_packages(str(ROOT), include=["sb3_pm", "sb3_pm.*"]))
    assert listed == found | {"sb3_pm.configs", "sb3_pm.configs.experiments"}


def test_only_the_experiments_a_user_runs_ship() -> None:
    """The package ships the paper's tables, the headline, the regimes, transfer, failures and
    families; the one-off research sweeps stay in the repository's research/experiments/."""
    assert {path.stem for path in EXPERIMENT_DIR.glob("*.yml")} == {
        "comparison",
        "ablation",
        "headline",
        "regime_100",
        "regime_200",
        "transfer",
        "zero_shot",
        "zero_shot_scaling",
        "failures",
        "families",
        "held_out",
    }
    assert not (PACKAGE / "configs").exists()  # in a checkout the configs are zoo/, never a link


@pytest.mark.parametrize("name", ["ippo", "ippo.yml", "zoo/ippo.yml", "ippo_paper", "ippo_split"])
def test_configs_resolve_by_name_from_any_folder(name, tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    assert resolve_config_path(name).resolve().parent == CONFIG_DIR.resolve()


@pytest.mark.parametrize(
    "name", ["comparison", "experiments/comparison.yml", "zoo/experiments/comparison.yml"]
)
def test_experiments_resolve_by_name_from_any_folder(name, tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    assert resolve_experiment_path(name).name == "comparison.yml"
    assert load_experiment(name).name == "comparison"


def test_a_local_file_wins_over_a_shipped_name(tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    Path("ippo.yml").write_text("default: {n_timesteps: 7}\n")
    assert resolve_config_path("ippo.yml") == Path("ippo.yml")


def test_unknown_names_list_what_ships(tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    with pytest.raises(FileNotFoundError, match="shipped configs: .*ippo_paper"):
        resolve_config_path("ipo")
    with pytest.raises(FileNotFoundError, match="shipped experiments: .*comparison"):
        resolve_experiment_path("zoo/experiments/nope.yml")


def test_the_default_config_is_the_measured_best_and_the_paper_one_is_kept() -> None:
    """zoo/ippo.yml is the best team measured, at the paper's budget on the published graphs, with
    planned territories and the filter's rule 9 at deployment on paper-50; zoo/ippo_split.yml keeps
    the default before them (split territories) and zoo/ippo_paper.yml the paper's reward and DCBF rules."""
    default = load_config(DEFAULT_CONFIG, "paper-50")
    assert default.n_timesteps == 50_000 and default.entry == "paper-50"
    assert default.env_kwargs["reward"] == {"clearing": 0.04, "territory": 0.04, "collision": 0.001}
    kwargs = default.hyperparams["policy_kwargs"]
    assert kwargs["dcbf_barrier"] is False and kwargs["avoid_collisions"] is True
    # The published graph by file path finds the same entry as by preset name.
    assert load_config(DEFAULT_CONFIG, str(DATA_DIR / "paper_50n_8t.graphml")).entry == "paper_50n_8t"
    assert default.env_kwargs["territories"] == "planned" and default.env_kwargs["advice_input"] is True
    split = load_config("ippo_split", "paper-50")
    assert "territories" not in split.env_kwargs and "advice_input" not in split.env_kwargs
    assert default.deploy_filter == {**(split.deploy_filter or {}), "leave_cleared": True}
    paper = load_config("ippo_paper", "paper-50")
    assert paper.n_timesteps == 50_000
    assert "reward" not in paper.env_kwargs  # the environment's default: the paper's reward
    assert "dcbf_barrier" not in paper.hyperparams["policy_kwargs"]


def test_train_with_no_config_from_outside_the_repository(tmp_path, monkeypatch, capsys) -> None:
    monkeypatch.chdir(tmp_path)
    assert main(["train", "--env", "paper-50", "--timesteps", "500", "--out", "run", "--no-progress"]) == 0
    resolved = yaml.safe_load(Path("run/config.yml").read_text())
    assert Path(resolved["source"]).name == "ippo.yml" and resolved["env"] == "paper-50"
    assert resolved["env_kwargs"]["reward"] == {"clearing": 0.04, "territory": 0.04, "collision": 0.001}
    assert Path("run/team/manifest.json").exists()


def test_no_tracked_file_points_outside_the_repository() -> None:
    """Nothing may rely on a sibling folder of the checkout: the project stands alone."""
    needle = "../" + "shared"
    try:
        files = subprocess.run(
            ["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True
        ).stdout.split()
    except (OSError, subprocess.CalledProcessError):  # not a git checkout: every project file
        skipped = {"build", "dist", "runs", "results", "__pycache__"}
        files = [
            str(path.relative_to(ROOT))
            for path in ROOT.rglob("*")
            if not any(part.startswith(".") or part in skipped or part.endswith(".egg-info")
                       for part in path.relative_to(ROOT).parts)
        ]  # fmt: skip
    assert files
    offenders = []
    for name in files:
        path = ROOT / name
        if path.is_file() and not path.is_symlink():
            try:
                if needle in path.read_text(errors="ignore"):
                    offenders.append(name)
            except OSError:
                continue
    assert not offenders, offenders
