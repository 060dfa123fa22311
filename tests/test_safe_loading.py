"""Loading a saved team or a checkpoint never runs code stored in its files.

Every file here carries a pickle payload that creates a marker file when it is unpickled. The first
test proves the payload works (SB3's own ``load`` runs it); every public loading route must then
leave the marker absent, and either load cleanly or refuse with one line.
"""

from __future__ import annotations

import base64
import hashlib
import io
import json
import pathlib
import pickle
import zipfile
from pathlib import Path

import cloudpickle
import numpy as np
import pytest
import torch as th

from sb3_pm.agents.deployment.saved_teams import OldTeamFormatError
from sb3_pm.agents.training.checkpoints import CheckpointError, CheckpointSchedule
from sb3_pm.agents.training.team import IndependentPPO
from sb3_pm.cli import main
from sb3_pm.errors import InputError
from sb3_pm.evaluation.harness import evaluate
from sb3_pm.evaluation.teams import load_trained_team
from sb3_pm.graphs import erdos_renyi
from sb3_pm.plain_state import StateFormatError, read_state, state_bytes, state_from_bytes
from tests.test_checkpoints import _assert_same
from tests.test_checkpoints import _state as _tensors

th.set_num_threads(1)

GRAPH = erdos_renyi(12, 0.3, n_targets=3, seed=1)
HYPERPARAMS = {
    "n_steps": 16,
    "batch_size": 16,
    "n_epochs": 2,
    "learning_rate": "lin_1e-3",
    "policy_kwargs": {"activation_fn": th.nn.Tanh},
}


class Payload:
    """Creates ``marker`` when unpickled: what a crafted file would do with a shell command."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self) -> tuple:
        return (pathlib.Path.touch, (self.marker,))


def _serialized(marker: Path) -> dict[str, str]:
    """A ``data`` entry as SB3 writes an object it cannot store as JSON."""
    return {
        ":type:": "<class 'Payload'>",
        ":serialized:": base64.b64encode(cloudpickle.dumps(Payload(marker))).decode(),
    }


def _poison_zip(path: Path, marker: Path) -> None:
    """Put the payload into every ``:serialized:`` entry of the zip's ``data`` (and a new one)."""
    with zipfile.ZipFile(path) as archive:
        entries = {name: archive.read(name) for name in archive.namelist()}
    data = json.loads(entries["data"])
    for key, value in data.items():
        if isinstance(value, dict) and ":serialized:" in value:
            data[key] = _serialized(marker)
    data["payload"] = _serialized(marker)
    entries["data"] = json.dumps(data).encode()
    with zipfile.ZipFile(path, "w") as archive:
        for name, content in entries.items():
            archive.writestr(name, content)


def _team(algo: str = "dcbf_ppo") -> IndependentPPO:
    return IndependentPPO(
        GRAPH, n_agents=2, algo=algo, n_envs=2, seed=5, hyperparams=HYPERPARAMS, env_kwargs={"max_cycles": 20}
    )


def _evaluate_cli(folder: Path, tmp_path: Path) -> int:
    """``sb3-pm evaluate --policy FOLDER`` for one 5-step episode; its exit status."""
    return main(
        [
            "evaluate",
            "--policy",
            str(folder),
            "--graph",
            str(_graph_file(tmp_path)),
            "--steps",
            "5",
            "--episodes",
            "1",
        ]
    )


def _metrics(team: object) -> dict[str, float]:
    return evaluate(team, GRAPH, episodes=2, seed=3, max_cycles=20).mean


def _make_old_format(folder: Path) -> None:
    """What a team saved before the current format looks like: format 1, no hyperparameters."""
    manifest = json.loads((folder / "manifest.json").read_text())
    manifest["format"] = manifest["format"].replace("/2", "/1")
    manifest.pop("hyperparams", None)
    manifest.pop("per_agent", None)
    (folder / "manifest.json").write_text(json.dumps(manifest))


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[th.Tensor], dict[str, float]]:
    """A trained team saved in the current format, its tensors and its evaluation."""
    team = _team()
    team.learn(64)
    folder = team.save(tmp_path_factory.mktemp("trained") / "team")
    result = folder, _tensors(team), _metrics(team)
    team.close()
    return result


def _copy(folder: Path, to: Path) -> Path:
    import shutil

    return Path(shutil.copytree(folder, to))


def test_the_payload_runs_when_sb3_unpickles_the_zip(trained, tmp_path) -> None:
    """The test files are really dangerous: SB3's own loader runs the payload."""
    from stable_baselines3.common.save_util import load_from_zip_file

    folder = _copy(trained[0], tmp_path / "team")
    marker = tmp_path / "MARKER"
    _poison_zip(folder / "agent_0.zip", marker)
    load_from_zip_file(folder / "agent_0.zip")
    assert marker.exists()


def test_a_team_round_trips_bit_for_bit(trained) -> None:
    folder, tensors, metrics = trained
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["format"] == "sb3_pm.team/2"
    assert manifest["hyperparams"]["policy_kwargs"] == {"activation_fn": "Tanh"}
    assert manifest["hyperparams"]["learning_rate"] == "lin_1e-3"
    loaded = IndependentPPO.load(folder)
    try:
        _assert_same(tensors, _tensors(loaded))
        assert loaded.num_timesteps == 64
        assert _metrics(loaded) == metrics
        loaded.learn(32, reset_num_timesteps=False)  # it trains on
        assert loaded.num_timesteps == 96
    finally:
        loaded.close()


def test_payloads_in_a_saved_team_never_run(trained, tmp_path, capsys) -> None:
    folder, tensors, metrics = trained
    folder = _copy(folder, tmp_path / "team")
    marker = tmp_path / "MARKER"
    for zip_file in folder.glob("*.zip"):
        _poison_zip(zip_file, marker)
    team = IndependentPPO.load(folder)
    _assert_same(tensors, _tensors(team))
    team.close()
    team = load_trained_team(folder)
    assert _metrics(team) == metrics
    team.close()
    code = _evaluate_cli(folder, tmp_path)
    capsys.readouterr()
    assert code == 0
    assert not marker.exists()


def test_a_pickle_in_place_of_the_tensors_is_refused_in_one_line(trained, tmp_path) -> None:
    """``policy.pth`` is read with ``weights_only=True``: a payload there is refused, not run."""
    folder = _copy(trained[0], tmp_path / "team")
    marker = tmp_path / "MARKER"
    with zipfile.ZipFile(folder / "agent_1.zip") as archive:
        entries = {name: archive.read(name) for name in archive.namelist()}
    entries["policy.pth"] = pickle.dumps(Payload(marker))
    with zipfile.ZipFile(folder / "agent_1.zip", "w") as archive:
        for name, content in entries.items():
            archive.writestr(name, content)
    with pytest.raises(InputError, match="agent_1.zip cannot be loaded") as error:
        IndependentPPO.load(folder)
    assert len(str(error.value).splitlines()) == 1
    assert not marker.exists()


def _graph_file(tmp_path: Path) -> Path:
    from sb3_pm.graphs import save_graphml

    return save_graphml(GRAPH, tmp_path / "g12.graphml", overwrite=True)


def test_an_old_format_team_is_refused_in_one_line(trained, tmp_path, capsys) -> None:
    folder = _copy(trained[0], tmp_path / "team")
    marker = tmp_path / "MARKER"
    for zip_file in folder.glob("*.zip"):
        _poison_zip(zip_file, marker)
    _make_old_format(folder)
    for load in (IndependentPPO.load, load_trained_team):
        with pytest.raises(InputError, match="old format .* can run code .*sb3-pm convert-team") as error:
            load(folder)
        assert len(str(error.value).splitlines()) == 1
    with pytest.raises(OldTeamFormatError):
        IndependentPPO.load(folder)
    code = _evaluate_cli(folder, tmp_path)
    err = capsys.readouterr().err
    assert code == 2 and "old format" in err and "convert-team" in err and len(err.strip().splitlines()) == 1
    assert not marker.exists()


def test_a_trusted_old_format_team_converts_bit_for_bit(trained, tmp_path, capsys) -> None:
    folder, tensors, metrics = trained
    old = _copy(folder, tmp_path / "old")
    _make_old_format(old)
    assert main(["convert-team", str(old), str(tmp_path / "new")]) == 0
    assert "converted" in capsys.readouterr().out
    converted = IndependentPPO.load(tmp_path / "new")
    try:
        _assert_same(tensors, _tensors(converted))
        assert _metrics(converted) == metrics
        per_agent = json.loads((tmp_path / "new" / "manifest.json").read_text())["per_agent"]
        assert per_agent["agent_0"]["policy_kwargs"]["activation_fn"] == "Tanh"
        assert per_agent["agent_0"]["learning_rate"] == "lin_0.001"
    finally:
        converted.close()
    with pytest.raises(InputError, match="not hold a team in an old format"):
        from sb3_pm import convert_team

        convert_team(tmp_path / "new", tmp_path / "again")


def test_a_centralized_team_round_trips_and_its_old_format_is_refused(tmp_path) -> None:
    from sb3_pm import CentralizedPPO, convert_team

    def central_team() -> CentralizedPPO:
        return CentralizedPPO(
            GRAPH,
            n_agents=2,
            seed=1,
            hyperparams={"n_steps": 16, "batch_size": 16, "n_epochs": 1},
            env_kwargs={"max_cycles": 20},
        )

    team = central_team()
    team.learn(16)
    folder = team.save(tmp_path / "central")
    loaded = CentralizedPPO.load(folder)
    before = list(team.model.policy.state_dict().values())
    _assert_same(before, list(loaded.model.policy.state_dict().values()))
    assert _metrics(loaded) == _metrics(team)
    loaded.close()
    team.close()
    marker = tmp_path / "MARKER"
    _poison_zip(folder / "shared.zip", marker)
    loaded = load_trained_team(folder)  # the payload is never read
    loaded.close()
    _make_old_format(folder)
    with pytest.raises(InputError, match="old format 'sb3_pm.centralized/1'"):
        load_trained_team(folder)
    assert not marker.exists()
    old = tmp_path / "old"
    team = central_team()
    team.save(old)
    fresh = list(team.model.policy.state_dict().values())
    team.close()
    _make_old_format(old)
    converted = CentralizedPPO.load(convert_team(old, tmp_path / "new"))
    _assert_same(fresh, list(converted.model.policy.state_dict().values()))
    converted.close()


def test_a_schedule_with_no_plain_form_is_refused_before_anything_is_written(tmp_path) -> None:
    team = IndependentPPO(
        GRAPH,
        n_agents=2,
        seed=1,
        hyperparams={"n_steps": 16, "batch_size": 16, "learning_rate": lambda progress: 1e-3 * progress},
    )
    try:
        with pytest.raises(InputError, match="learning_rate is a function") as error:
            team.save(tmp_path / "team")
        assert len(str(error.value).splitlines()) == 1
        assert not (tmp_path / "team").exists()
        with pytest.raises(InputError, match="learning_rate is a function"):  # before any training
            team.learn(32, checkpoints=CheckpointSchedule(tmp_path / "checkpoints"))
        assert team.num_timesteps == 0
    finally:
        team.close()


def test_a_manifest_naming_other_code_is_refused(trained, tmp_path) -> None:
    folder = _copy(trained[0], tmp_path / "team")
    manifest = json.loads((folder / "manifest.json").read_text())
    manifest["hyperparams"]["policy_kwargs"]["activation_fn"] = "os:system"
    (folder / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(InputError, match="a saved team names no other code"):
        IndependentPPO.load(folder)


def _rewrite_checksums(checkpoint: Path) -> None:
    """What a forger would do: make checkpoint.json agree with the edited files."""
    record = json.loads((checkpoint / "checkpoint.json").read_text())
    record["sha256"] = {
        name: hashlib.sha256((checkpoint / name).read_bytes()).hexdigest() for name in record["sha256"]
    }
    (checkpoint / "checkpoint.json").write_text(json.dumps(record))


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("checkpoints")
    _team().learn(96, checkpoints=CheckpointSchedule(folder, every=2)).close()
    return folder / "rollout_000002"


def test_a_checkpoint_holds_no_pickle(checkpoint) -> None:
    assert sorted(p.name for p in checkpoint.iterdir() if p.suffix not in (".zip", ".graphml")) == [
        "checkpoint.json",
        "manifest.json",
        "state.json",
        "state.npz",
    ]
    with np.load(checkpoint / "state.npz", allow_pickle=False) as arrays:
        assert all(arrays[key].dtype != object for key in arrays.files)


def test_payloads_in_a_checkpoint_never_run(checkpoint, tmp_path) -> None:
    marker = tmp_path / "MARKER"
    poisoned = _copy(checkpoint, tmp_path / "rollout_000002")
    for zip_file in poisoned.glob("*.zip"):
        _poison_zip(zip_file, marker)
    _rewrite_checksums(poisoned)
    team = IndependentPPO.from_checkpoint(poisoned)  # the zips' payloads are never read
    assert team.num_timesteps == 32 * 2
    team.close()

    # The state's arrays replaced by a pickle (an object array in an .npz, and a bare pickle).
    with (poisoned / "state.npz").open("wb") as handle:
        np.savez(handle, a0=np.array([Payload(marker)], dtype=object))
    _rewrite_checksums(poisoned)
    with pytest.raises(CheckpointError) as error:
        IndependentPPO.from_checkpoint(poisoned)
    assert len(str(error.value).splitlines()) == 1
    (poisoned / "state.npz").write_bytes(pickle.dumps(Payload(marker)))
    _rewrite_checksums(poisoned)
    with pytest.raises(CheckpointError) as error:
        IndependentPPO.from_checkpoint(poisoned)
    assert len(str(error.value).splitlines()) == 1
    assert not marker.exists()


def test_a_state_file_with_anything_but_plain_state_is_refused(checkpoint, tmp_path) -> None:
    state = tmp_path / "state.json"
    for tree in ({"__reduce__": ["os", "system"]}, {"__generator__": {"bit_generator": "os.system"}}):
        state.write_text(json.dumps(tree))
        with pytest.raises(StateFormatError):
            read_state(state, checkpoint / "state.npz")


def test_plain_state_in_memory_round_trips_and_never_unpickles(tmp_path) -> None:
    """The form a plan search's worker process reads and answers in (sb3_pm.planning.search_worker)."""
    value = {"groups": ((3, 7), ()), "predicted": 33.07, "starts": np.array([1, 2]), "initial": None}
    back = state_from_bytes(state_bytes(value))
    assert back["groups"] == ((3, 7), ()) and back["predicted"] == 33.07 and back["initial"] is None
    assert np.array_equal(back["starts"], value["starts"])
    marker = tmp_path / "MARKER"
    for payload in (pickle.dumps(Payload(marker)), _object_array_npz(marker), b"not an archive"):
        with pytest.raises(StateFormatError):
            state_from_bytes(payload)
    assert not marker.exists()


def _object_array_npz(marker: Path) -> bytes:
    buffer = io.BytesIO()
    np.savez(
        buffer, __tree__=np.frombuffer(b'{"__array__": "a0"}', dtype=np.uint8), a0=np.array([Payload(marker)])
    )
    return buffer.getvalue()


def test_an_old_checkpoint_is_refused_in_one_line(checkpoint, tmp_path) -> None:
    old = _copy(checkpoint, tmp_path / "rollout_000002")
    record = json.loads((old / "checkpoint.json").read_text())
    record["format"] = "sb3_pm.checkpoint/1"
    (old / "checkpoint.json").write_text(json.dumps(record))
    with pytest.raises(CheckpointError, match="old format .* pickle") as error:
        IndependentPPO.from_checkpoint(old)
    assert len(str(error.value).splitlines()) == 1
