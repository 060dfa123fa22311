"""``sb3-pm evaluate`` and ``sb3-pm compare``: outputs, JSON schema, trained-team loading, one-line errors."""

from __future__ import annotations

import json
import sys

import pytest

from sb3_pm.baselines import make_team
from sb3_pm.cli import main


def run_cli(capsys, *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    captured = capsys.readouterr()
    return code, captured.out, captured.err


class TestEvaluate:
    def test_prints_table_and_writes_json(self, capsys, tmp_path) -> None:
        out_json = tmp_path / "r.json"
        code, out, _ = run_cli(
            capsys, "evaluate", "--policy", "grazing", "--graph", "paper-50", "--agents", "3",
            "--steps", "20", "--episodes", "2", "--seed", "5", "--json", str(out_json),
        )  # fmt: skip
        assert code == 0
        assert "avg_uncertainty" in out and "max_neglect" in out and "grazing on paper-50" in out
        payload = json.loads(out_json.read_text())
        assert set(payload) == {"episodes", "mean", "std", "config"}
        assert [e["seed"] for e in payload["episodes"]] == [5, 6]
        assert {"avg_uncertainty", "max_neglect", "collisions"} <= set(payload["episodes"][0])
        assert (payload["config"]["n_agents"], payload["config"]["max_cycles"]) == (3, 20)
        assert (payload["config"]["policy"], payload["config"]["graph"]) == ("grazing", "paper-50")

    def test_graphml_and_gif(self, capsys, tmp_path, published_graphs) -> None:
        gif, graph = tmp_path / "e.gif", str(published_graphs / "paper_50n_8t.graphml")
        code, _, _ = run_cli(
            capsys, "evaluate", "--policy", "random", "--graph", graph,
            "--steps", "3", "--episodes", "1", "--gif", str(gif),
        )  # fmt: skip
        assert code == 0
        assert gif.read_bytes()[:3] == b"GIF"

    @pytest.mark.parametrize(
        ("args", "message"),
        [
            (["--policy", "nope"], "unknown policy 'nope'"),
            (["--policy", "./no/such/team"], "trained team directory not found"),
            (["--policy", "random", "--graph", "missing.graphml"], "graph file not found"),
            (["--policy", "random", "--graph", "bogus"], "unknown graph 'bogus'"),
            (["--policy", "random", "--episodes", "0"], "--episodes must be at least 1"),
            (["--policy", "random", "--steps", "0"], "--steps must be at least 1"),
            (["--policy", "random", "--agents", "0"], "--agents must be at least 1"),
            (["--policy", "random", "--agents", "51"], "more agents (51) than nodes"),
            (["--policy", "random", "--json", "/no/such/dir/r.json"], "output directory does not exist"),
            (["--policy", "territory_patrol", "--territories", "planned_tours"], "is told neither"),
        ],
    )
    def test_errors_are_one_line(self, capsys, args, message) -> None:
        code, out, err = run_cli(capsys, "evaluate", "--steps", "5", "--episodes", "1", *args)
        assert code == 2
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("sb3-pm evaluate: error:")
        assert message in lines[0]

    def test_malformed_graph(self, capsys, tmp_path) -> None:
        bad = tmp_path / "bad.graphml"
        bad.write_text("<graphml><not closed")
        code, _, err = run_cli(capsys, "evaluate", "--policy", "random", "--graph", str(bad))
        assert code == 2 and len(err.strip().splitlines()) == 1 and "bad.graphml" in err

    def test_trained_team_directory(self, capsys, tmp_path, monkeypatch) -> None:
        loaded = []

        class FakePPO:
            @staticmethod
            def load(path, graph=None, device="cpu"):
                loaded.append((path, device))
                team = make_team("sit_on_nodes")
                # a trained team of 4 that cannot be resized, trained with these env settings
                team.n_agents, team.resizable = 4, False
                team.env_settings = lambda: {"obs_radius": 2}
                return team

        # Patch the class, not the module: the loader also imports the centralized team's module,
        # which reads other names from sb3_pm.agents.training.team.
        monkeypatch.setattr("sb3_pm.agents.training.team.IndependentPPO", FakePPO)
        team_dir = tmp_path / "my_team"
        team_dir.mkdir()
        argv = ["evaluate", "--policy", str(team_dir), "--steps", "5", "--episodes", "1"]
        code, out, _ = run_cli(capsys, *argv)
        assert code == 0 and loaded and loaded[0] == (team_dir, "cpu")
        assert "my_team on paper-50" in out
        # The team's own env options are used (obs_radius), the episode length stays ours.
        code, _, _ = run_cli(capsys, *argv, "--json", str(tmp_path / "r.json"))
        config = json.loads((tmp_path / "r.json").read_text())["config"]
        assert config["env_kwargs"] == {"obs_radius": 2} and config["max_cycles"] == 5
        code, _, err = run_cli(capsys, *argv, "--agents", "3")
        # This fake team is not resizable, so it cannot be deployed with another size.
        assert code == 2 and "has 4 agents and cannot be deployed with another number; pass --agents 4" in err
        # --device reaches the loader as given (here where no GPU is needed: the team is a fake)
        monkeypatch.setattr("sb3_pm.commands.options.check_device", lambda device, flag: None)
        code, _, _ = run_cli(capsys, *argv, "--device", "cuda")
        assert code == 0 and loaded[-1] == (team_dir, "cuda")

    def test_territories_offers_every_convention(self) -> None:
        from sb3_pm.cli import build_parser
        from sb3_pm.planning.conventions import TERRITORY_CONVENTIONS

        evaluate = build_parser()._subparsers._group_actions[0].choices["evaluate"]  # type: ignore[union-attr]
        option = next(action for action in evaluate._actions if "--territories" in action.option_strings)
        assert tuple(option.choices) == TERRITORY_CONVENTIONS

    def test_territories_put_a_convention_over_the_teams_own(self, capsys, tmp_path, monkeypatch) -> None:
        told = {"advice_input": True, "graph_knowledge": "known", "target_knowledge": "known"}

        class FakePPO:
            @staticmethod
            def load(path, graph=None, device="cpu"):
                team = make_team("sit_on_nodes")  # acts on its own; the env's advice follows the convention
                team.n_agents, team.resizable = 4, False
                team.env_settings = lambda: {**told, "territories": "planned"}
                return team

        monkeypatch.setattr("sb3_pm.agents.training.team.IndependentPPO", FakePPO)
        team_dir = tmp_path / "told_team"
        team_dir.mkdir()
        result = tmp_path / "r.json"
        argv = ["evaluate", "--policy", str(team_dir), "--steps", "5", "--episodes", "1"]
        argv += ["--json", str(result)]
        code, _, _ = run_cli(capsys, *argv, "--territories", "planned_tours")
        assert code == 0
        assert json.loads(result.read_text())["config"]["env_kwargs"]["territories"] == "planned_tours"
        result.unlink()
        code, _, _ = run_cli(capsys, *argv)  # without the option, the team's own
        assert json.loads(result.read_text())["config"]["env_kwargs"]["territories"] == "planned"

    def test_a_trained_team_deploys_with_its_own_size_by_default(self, capsys, tmp_path, monkeypatch) -> None:
        class FakePPO:
            @staticmethod
            def load(path, graph=None, device="cpu"):
                team = make_team("sit_on_nodes")
                team.n_agents, team.env_kwargs = 3, {}
                return team

        monkeypatch.setattr("sb3_pm.agents.training.team.IndependentPPO", FakePPO)
        team_dir = tmp_path / "three"
        team_dir.mkdir()
        out_json = tmp_path / "r.json"
        argv = [
            "evaluate",
            "--policy",
            str(team_dir),
            "--steps",
            "5",
            "--episodes",
            "1",
            "--json",
            str(out_json),
        ]
        code, _, err = run_cli(capsys, *argv)
        assert code == 0 and "deploying" not in err  # no silent resize, and no resize at all
        assert json.loads(out_json.read_text())["config"]["n_agents"] == 3
        # A rule-based policy has no size of its own: the documented 4.
        code, _, _ = run_cli(capsys, "evaluate", "--policy", "grazing", "--steps", "5", "--episodes", "1",
                             "--json", str(out_json))  # fmt: skip
        assert code == 0 and json.loads(out_json.read_text())["config"]["n_agents"] == 4

    def test_trained_team_without_learner(self, capsys, tmp_path, monkeypatch) -> None:
        monkeypatch.setitem(sys.modules, "sb3_pm.agents.training.team", None)  # import fails
        code, _, err = run_cli(
            capsys, "evaluate", "--policy", str(tmp_path), "--steps", "5", "--episodes", "1"
        )
        assert code == 2 and "IndependentPPO is unavailable" in err and len(err.strip().splitlines()) == 1


class TestCompare:
    def test_writes_reports(self, capsys, tmp_path) -> None:
        out_dir = tmp_path / "cmp"
        code, out, _ = run_cli(
            capsys, "compare", "--policies", "random", "grazing", "--graphs", "paper-50", "--seeds", "0", "1",
            "--episodes", "2", "--steps", "10", "--out", str(out_dir),
        )  # fmt: skip
        assert code == 0
        assert out.startswith("| Algorithm | Avg. Uncertainty | SD | Max Neglect | SD |")
        names = {p.name for p in out_dir.iterdir()}
        assert names == {
            "table.md",
            "table.csv",
            "table.tex",
            "anova.txt",
            "by_graph.md",
            "effects.md",
            "results.json",
            "uncertainty.png",
            "table.png",
            "runs.md",
            "marl_eval.json",
            "performance_profile.png",
        }
        assert "avg_uncertainty: F(1, 6)" in (out_dir / "anova.txt").read_text()
        # A second run refuses to overwrite, unless asked.
        argv = ["compare", "--policies", "random", "--episodes", "1", "--steps", "5", "--out", str(out_dir)]
        code, _, err = run_cli(capsys, *argv)
        assert code == 2 and "not empty" in err
        code, _, _ = run_cli(capsys, *argv, "--overwrite")
        assert code == 0

    @pytest.mark.parametrize(
        ("args", "message"),
        [
            (["--policies", "random", "nope"], "unknown policy 'nope'"),
            (["--policies", "random", "random"], "lists a policy twice"),
            (["--policies", "random", "--graphs", "paper-50", "gone.graphml"], "graph file not found"),
            (["--policies", "random", "--episodes", "0"], "--episodes must be at least 1"),
        ],
    )
    def test_errors(self, capsys, tmp_path, args, message) -> None:
        code, _, err = run_cli(capsys, "compare", "--steps", "5", "--out", str(tmp_path / "o"), *args)
        assert code == 2 and message in err and len(err.strip().splitlines()) == 1
        assert not (tmp_path / "o").exists()  # nothing written before the inputs are checked


@pytest.mark.parametrize(
    ("manifest", "expected"),
    [
        ({"format": "sb3_pm.team/1", "name": "sb3_pm.centralized/1 look-alike"}, "independent"),
        ({"format": "sb3_pm.centralized/1"}, "centralized"),
    ],
)
def test_saved_team_type_comes_from_the_manifest_format(monkeypatch, tmp_path, manifest, expected) -> None:
    """Not from a substring of the manifest: a name that mentions another format changes nothing."""
    from sb3_pm.evaluation.teams import load_trained_team

    def fake(kind):
        return type(kind, (), {"load": staticmethod(lambda path, graph=None, device="cpu": kind)})

    monkeypatch.setattr("sb3_pm.agents.training.team.IndependentPPO", fake("independent"))
    monkeypatch.setattr("sb3_pm.sharing.centralized.CentralizedPPO", fake("centralized"))
    (tmp_path / "team").mkdir()
    (tmp_path / "team" / "manifest.json").write_text(json.dumps(manifest))
    assert load_trained_team(tmp_path) == expected  # a run folder: the team is in team/
    assert load_trained_team(str(tmp_path)) == expected  # a path given as a string works too
