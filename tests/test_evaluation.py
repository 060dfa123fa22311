"""Evaluation harness: metrics by hand on tiny graphs, seeding, aggregates, statistics, reports, plots."""

from __future__ import annotations

import csv
import io
import json
import math

import numpy as np
import pytest
from scipy import stats

from sb3_pm.baselines import Team, make_team
from sb3_pm.envs.metrics import METRIC_NAMES
from sb3_pm.evaluation import (
    Comparison,
    Summary,
    anova,
    anova_text,
    by_graph_markdown,
    compare,
    csv_table,
    effect,
    effects,
    effects_markdown,
    evaluate,
    latex_table,
    markdown_table,
    plot_table,
    plot_uncertainty,
    record_gif,
    resolve_team,
    summarize,
    summarize_by_graph,
    team_seed,
)
from sb3_pm.evaluation.harness import EpisodeRecord, EvaluationResult
from sb3_pm.evaluation.plots import line_colors
from sb3_pm.evaluation.teams import PolicyError
from tests.conftest import path_graph


class ScriptedTeam(Team):
    """Plays a fixed list of joint moves (one list of nodes per step), then stays."""

    name = "scripted"

    def __init__(self, moves: list[list[int]]) -> None:
        self.moves = moves

    def reset(self, env, seed=None) -> None:
        super().reset(env, seed)
        self.k = 0

    def predict_dict(self, observations, deterministic=True):
        agents = list(observations)
        if self.k < len(self.moves):
            move = self.moves[self.k]
        else:
            move = [int(observations[a]["position"]) for a in agents]
        self.k += 1
        return dict(zip(agents, move))


class TestMetricsByHand:
    def test_three_node_path(self) -> None:
        # 0 - 1 - 2, targets 0 and 2, one agent starting on 1, K = 6.
        # Moves: 0, 0, 1, 2, 2, 2.  u after each step (target 0, target 2):
        #   k0 at 0: (0, 1)   k1 at 0: (0, 2)   k2 at 1: (1, 3)
        #   k3 at 2: (2, 2)   k4 at 2: (3, 1)   k5 at 2: (4, 0)
        # sums 1, 2, 4, 4, 4, 4 -> avg 19/6.
        # Neglect runs: target 0 unvisited on k2..k5 -> 4; target 2 unvisited on k0..k2 -> 3. max 4.
        graph = path_graph(3, [0, 2])
        team = ScriptedTeam([[0], [0], [1], [2], [2], [2]])
        result = evaluate(
            team, graph, n_agents=1, episodes=1, max_cycles=6, env_kwargs={"initial_positions": [1]}
        )
        record = result.episodes[0]
        assert record.trace.tolist() == [1, 2, 4, 4, 4, 4]
        assert record.metrics["avg_uncertainty"] == pytest.approx(19 / 6)
        assert record.metrics["max_neglect"] == 4
        assert record.metrics["peak_uncertainty"] == 4
        assert record.metrics["collisions"] == 0
        assert record.metrics["saturated_fraction"] == 0

    def test_never_visited_target_and_cap_and_collisions(self) -> None:
        # 0 - 1 - 2, target 2 only, u_max 3, two agents sitting together on node 0 for K = 5.
        # u of target 2: 1, 2, 3, 3, 3 -> avg 12/5, saturated on 3 of 5 steps, neglect K = 5.
        # Both agents share node 0 every step: 2 agent-collisions per step -> 10.
        graph = path_graph(3, [2])
        team = ScriptedTeam([])
        result = evaluate(
            team,
            graph,
            n_agents=2,
            episodes=1,
            max_cycles=5,
            env_kwargs={"initial_positions": [0, 0], "u_max": 3},
        )
        metrics = result.episodes[0].metrics
        assert metrics["avg_uncertainty"] == pytest.approx(12 / 5)
        assert metrics["max_neglect"] == 5
        assert metrics["saturated_fraction"] == pytest.approx(3 / 5)
        assert metrics["peak_uncertainty"] == 3
        assert metrics["collisions"] == 10


class TestEvaluate:
    def test_records_seeds_and_aggregates(self) -> None:
        result = evaluate(make_team("random"), "paper-50", n_agents=4, episodes=3, seed=7, max_cycles=30)
        assert [r.episode for r in result.episodes] == [0, 1, 2]
        assert [r.seed for r in result.episodes] == [7, 8, 9]
        assert [r.team_seed for r in result.episodes] == [team_seed(s) for s in (7, 8, 9)]
        assert len({r.team_seed for r in result.episodes} | {7, 8, 9}) == 6
        values = result.values("avg_uncertainty")
        assert result.mean["avg_uncertainty"] == pytest.approx(values.mean())
        assert result.std["avg_uncertainty"] == pytest.approx(values.std(ddof=1))
        assert result.traces.shape == (3, 30)
        assert np.allclose(result.traces.mean(axis=1), values)

    def test_reproducible(self) -> None:
        a = evaluate(make_team("random"), "paper-50", episodes=2, seed=3, max_cycles=25)
        b = evaluate(make_team("random"), "paper-50", episodes=2, seed=3, max_cycles=25)
        assert a.to_dict() == b.to_dict()
        c = evaluate(make_team("random"), "paper-50", episodes=2, seed=4, max_cycles=25)
        assert a.to_dict()["episodes"] != c.to_dict()["episodes"]

    def test_json_schema(self) -> None:
        result = evaluate(make_team("grazing"), "paper-50", n_agents=3, episodes=2, seed=0, max_cycles=20)
        payload = json.loads(json.dumps(result.to_dict()))
        assert set(payload) == {"episodes", "mean", "std", "config"}
        metrics = set(METRIC_NAMES)  # every metric the env declares reaches the JSON
        assert {"avg_uncertainty", "max_neglect", "idle_fraction"} <= metrics
        assert len(payload["episodes"]) == 2
        for episode in payload["episodes"]:
            assert metrics | {"episode", "seed", "team_seed"} <= set(episode)
            assert all(isinstance(v, (int, float)) for v in episode.values())
        assert metrics <= set(payload["mean"]) and set(payload["mean"]) == set(payload["std"])
        config = payload["config"]
        assert config["policy"] == "grazing" and config["n_agents"] == 3 and config["max_cycles"] == 20
        assert config["episodes"] == 2 and config["seed"] == 0

    def test_single_episode_sd_is_zero(self) -> None:
        result = evaluate(make_team("sit_on_nodes"), "paper-50", episodes=1, max_cycles=10)
        assert all(value == 0.0 for value in result.std.values())

    def test_zero_episodes(self) -> None:
        with pytest.raises(ValueError, match="episodes must be at least 1"):
            evaluate(make_team("random"), "paper-50", episodes=0)


def fake_result(policy: str, values: list[float], neglect: list[float] | None = None) -> EvaluationResult:
    neglect = neglect or values
    episodes = [
        EpisodeRecord(i, i, 0, {"avg_uncertainty": v, "max_neglect": n}, np.array([v]))
        for i, (v, n) in enumerate(zip(values, neglect))
    ]
    return EvaluationResult(policy, "g", {}, episodes)


class TestStatistics:
    def test_pooled_summary(self) -> None:
        table = summarize({"a": [fake_result("a", [1, 2]), fake_result("a", [3])]})
        summary = table["a"]["avg_uncertainty"]
        assert summary == Summary(2.0, 1.0, 3)

    def test_anova_matches_scipy(self) -> None:
        groups = {
            "a": [fake_result("a", [1, 2, 3])],
            "b": [fake_result("b", [4, 6, 8])],
            "c": [fake_result("c", [2, 2.5, 3.5])],
        }
        result = anova(groups, "avg_uncertainty")
        expected = stats.f_oneway([1, 2, 3], [4, 6, 8], [2, 2.5, 3.5])
        assert result.statistic == pytest.approx(expected.statistic)
        assert result.p_value == pytest.approx(expected.pvalue)
        assert (result.df_between, result.df_within) == (2, 6)
        assert result.groups == ("a", "b", "c")

    def test_paired_effect_by_hand(self) -> None:
        # Same env seeds (0, 1, 2) on the same graph: paired. Differences 1, 2, 3 -> mean 2, SD 1.
        policy, reference = fake_result("p", [11, 22, 33]), fake_result("r", [10, 20, 30])
        e = effect([policy], [reference], "g", "avg_uncertainty", names=("p", "r"))
        assert e.paired and e.n == 3
        assert e.difference == pytest.approx(2.0) and e.ratio == pytest.approx(22 / 20)
        assert e.cohens_d == pytest.approx(2.0)  # mean difference / SD of differences
        half_width = stats.t.ppf(0.975, 2) * 1.0 / math.sqrt(3)
        assert (e.ci_low, e.ci_high) == pytest.approx((2 - half_width, 2 + half_width))
        assert e.p_value == pytest.approx(stats.ttest_rel([11, 22, 33], [10, 20, 30]).pvalue)

    def test_run_level_test_pairs_the_runs_means(self) -> None:
        def run(policy: str, seed: int, values: list[float]) -> EvaluationResult:
            records = [
                EpisodeRecord(i, seed + i, 0, {"avg_uncertainty": v}, np.zeros(1))
                for i, v in enumerate(values)
            ]
            return EvaluationResult(policy, "g", {"seed": seed}, records)

        policy = [run("p", 0, [11, 11]), run("p", 1000, [21, 21]), run("p", 2000, [33, 33])]
        reference = [run("r", 0, [10, 10]), run("r", 1000, [19, 19]), run("r", 2000, [30, 30])]
        e = effect(policy, reference, "g", "avg_uncertainty")
        assert e.paired and e.n == 6 and e.n_runs == 3
        # Run means 11, 21, 33 against 10, 19, 30.
        assert e.p_value_runs == pytest.approx(stats.ttest_rel([11, 21, 33], [10, 19, 30]).pvalue)
        assert e.p_value_runs > e.p_value  # 3 replicates say less than 6 episodes seem to

    def test_runs_on_the_same_episodes_are_all_kept(self) -> None:
        """Training seeds evaluated on one set of env seeds: every run's episodes count, and the
        k-th run of one side pairs with the k-th of the other (none is overwritten by the last)."""

        def run(policy: str, values: list[float]) -> EvaluationResult:
            records = [
                EpisodeRecord(i, 11 + i, 0, {"avg_uncertainty": v}, np.zeros(1)) for i, v in enumerate(values)
            ]
            return EvaluationResult(policy, "g", {"seed": 11}, records)

        policy = [run("p", [11, 12]), run("p", [21, 23]), run("p", [33, 30])]
        reference = [run("r", [10, 10]), run("r", [19, 20]), run("r", [30, 31])]
        e = effect(policy, reference, "g", "avg_uncertainty")
        assert e.paired and e.n == 6 and e.n_runs == 3
        assert e.mean == pytest.approx(np.mean([11, 12, 21, 23, 33, 30]))
        assert e.reference_mean == pytest.approx(np.mean([10, 10, 19, 20, 30, 31]))
        pairs = ([11, 12, 21, 23, 33, 30], [10, 10, 19, 20, 30, 31])
        assert e.p_value == pytest.approx(stats.ttest_rel(*pairs).pvalue)
        assert e.p_value_runs == pytest.approx(stats.ttest_rel([11.5, 22, 31.5], [10, 19.5, 30.5]).pvalue)

    def test_unpaired_effect_uses_welch(self) -> None:
        policy = fake_result("p", [1, 2, 3])
        reference = EvaluationResult(
            "r",
            "g",
            {},
            [
                EpisodeRecord(i, 100 + i, 0, {"avg_uncertainty": v}, np.zeros(1))
                for i, v in enumerate([5, 7, 9, 11])
            ],
        )
        e = effect([policy], [reference], "g", "avg_uncertainty")
        assert not e.paired
        assert e.difference == pytest.approx(2.0 - 8.0)
        expected = stats.ttest_ind([1, 2, 3], [5, 7, 9, 11], equal_var=False)
        assert e.p_value == pytest.approx(expected.pvalue)
        assert e.ci_low < e.difference < e.ci_high

    def test_effects_keep_graphs_apart(self) -> None:
        def on(graph: str, policy: str, values: list[float]) -> EvaluationResult:
            result = fake_result(policy, values)
            result.graph = graph
            return result

        by_policy = {
            "ref": [on("small", "ref", [10, 12]), on("large", "ref", [100, 120])],
            "other": [on("small", "other", [5, 6]), on("large", "other", [200, 240])],
        }
        comparison = Comparison(results=by_policy)
        within = comparison.anovas_by_graph["large"][0]
        assert within.statistic == pytest.approx(stats.f_oneway([100, 120], [200, 240]).statistic)
        assert "within small:" in comparison.anova_report()
        rows = effects(by_policy, "ref")
        assert [(e.graph, e.policy) for e in rows] == [("small", "other"), ("large", "other")]
        assert [e.ratio for e in rows] == pytest.approx([0.5, 2.0])
        by_graph = summarize_by_graph(by_policy)
        assert by_graph["other"]["large"] == Summary(220.0, pytest.approx(math.sqrt(800)), 2)
        with pytest.raises(ValueError, match="unknown reference"):
            effects(by_policy, "nobody")
        assert "Difference" in effects_markdown(rows) and "small" in by_graph_markdown(
            {"avg_uncertainty": by_graph}
        )

    def test_anova_undefined_cases(self) -> None:
        assert math.isnan(anova({"a": [fake_result("a", [1, 2])]}, "avg_uncertainty").statistic)
        assert math.isnan(
            anova({"a": [fake_result("a", [1])], "b": [fake_result("b", [2])]}, "avg_uncertainty").statistic
        )
        text = anova_text([anova({"a": [fake_result("a", [1, 2])]}, "avg_uncertainty")])
        assert "undefined" in text


class TestReports:
    table = summarize(
        {
            "random": [fake_result("random", [700, 710], [100, 120])],
            "sit_on_nodes": [fake_result("s", [360, 360], [500, 500])],
        }
    )

    def test_markdown(self) -> None:
        lines = markdown_table(self.table).splitlines()
        assert lines[0] == "| Algorithm | Avg. Uncertainty | SD | Max Neglect | SD |"
        assert lines[2] == "| random | 705.0 | 7.1 | 110.0 | 14.1 |"
        assert lines[3] == "| sit_on_nodes | 360.0 | 0.0 | 500.0 | 0.0 |"

    def test_csv(self) -> None:
        rows = list(csv.DictReader(io.StringIO(csv_table(self.table))))
        assert rows[0]["algorithm"] == "random"
        assert float(rows[0]["avg_uncertainty_mean"]) == 705.0
        assert float(rows[0]["max_neglect_sd"]) == pytest.approx(np.std([100, 120], ddof=1))
        assert rows[1]["n"] == "2"

    def test_latex(self) -> None:
        text = latex_table(self.table)
        assert r"\begin{tabular}{lrrrr}" in text
        assert r"sit\_on\_nodes & 360.0 & 0.0 & 500.0 & 0.0 \\" in text


class TestPlotsAndGif:
    def test_plots_are_pngs(self, tmp_path) -> None:
        results = {
            name: [evaluate(make_team(name), "paper-50", episodes=2, max_cycles=15)]
            for name in ("random", "grazing")
        }
        for path in (
            plot_uncertainty(results, tmp_path / "u.png"),
            plot_table(summarize(results), tmp_path / "t.png"),
        ):
            assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    @pytest.mark.parametrize("n", [3, 10, 16, 25])
    def test_line_colors_are_distinct(self, n: int) -> None:
        """A sweep's lines never share a colour (matplotlib's default cycle repeats after 10)."""
        colors = line_colors(n)
        assert len(colors) == n and len(set(colors)) == n

    def test_many_policies_plot(self, tmp_path) -> None:
        """16 lines (a tuning sweep): the legend goes beside the axes, and the figure still saves."""
        result = evaluate(make_team("random"), "paper-50", episodes=1, max_cycles=5)
        path = plot_uncertainty({f"variant {i}": [result] for i in range(16)}, tmp_path / "many.png")
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    def test_gif(self, tmp_path) -> None:
        import imageio.v3 as iio

        record = record_gif(make_team("grazing"), "paper-50", tmp_path / "e.gif", seed=2, max_cycles=4)
        frames = iio.imread(tmp_path / "e.gif", index=None)
        assert frames.shape[0] == 5  # the reset frame plus one per step
        same = evaluate(make_team("grazing"), "paper-50", episodes=1, seed=2, max_cycles=4).episodes[0]
        assert record.metrics == same.metrics

    def test_blitted_frames_equal_a_full_redraw(self) -> None:
        """Only the changing artists are redrawn per frame; nothing of an earlier frame may remain."""
        from sb3_pm.envs.rendering import GraphRenderer
        from sb3_pm.graphs import resolve_graph

        graph = resolve_graph("paper-50")
        renderer = GraphRenderer(graph, u_max=100)
        u_a, u_b = np.arange(graph.n_nodes) % 101, np.full(graph.n_nodes, 100)
        first = renderer.draw(u_a, np.array([0, 1, 2, 3]), 0)
        other = renderer.draw(u_b, np.array([10, 11, 12, 13]), 1)
        again = renderer.draw(u_a, np.array([0, 1, 2, 3]), 0)
        assert (first == again).all() and (first != other).any()
        # A full redraw of the same state, every artist drawn the ordinary way, gives the same pixels.
        for artist in (renderer.targets, renderer.agents, renderer.title, *renderer.labels):
            artist.set_animated(False)
        renderer.figure.canvas.draw()
        full = np.asarray(renderer.figure.canvas.buffer_rgba())[:, :, :3]
        renderer.close()
        assert (full == again).all()
        # The window mode (human) draws without blitting, the same picture.
        plain = GraphRenderer(graph, u_max=100, blit=False)
        assert (plain.draw(u_a, np.array([0, 1, 2, 3]), 0) == again).all()
        plain.close()

    def test_gif_keeps_the_frames(self, tmp_path) -> None:
        import imageio.v3 as iio

        from sb3_pm.evaluation.gif import write_gif

        rng = np.random.default_rng(0)
        frames = [np.full((20, 30, 3), value, dtype=np.uint8) for value in (0, 90, 255)]
        frames.append(rng.integers(0, 256, (20, 30, 3), dtype=np.uint8))
        back = iio.imread(write_gif(frames, tmp_path / "f.gif"), index=None)[..., :3]
        assert back.shape == (4, 20, 30, 3)
        assert (back[:3] == np.stack(frames[:3])).all()  # flat colours are in the palette exactly
        with pytest.raises(ValueError, match="at least one frame"):
            write_gif([], tmp_path / "none.gif")


class TestCompareAndResolve:
    def test_compare_writes_everything(self, tmp_path) -> None:
        comparison = compare(
            {"random": lambda graph: make_team("random"), "grazing": lambda graph: make_team("grazing")},
            ["paper-50"],
            seeds=[0, 1],
            episodes=2,
            max_cycles=15,
        )
        assert [r.config["seed"] for r in comparison.results["random"]] == [0, 1000]
        assert all(len(r.episodes) == 2 for r in comparison.results["grazing"])
        names = {p.name for p in comparison.write(tmp_path)}
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
        payload = json.loads((tmp_path / "results.json").read_text())
        assert payload["table"]["random"]["avg_uncertainty"]["n"] == 4
        # Both policies ran on the same episodes, so grazing is compared with random (the first) paired.
        [grazing] = payload["effects"]
        assert grazing["policy"] == "grazing" and grazing["reference"] == "random"
        assert grazing["paired"] and grazing["n"] == 4

    def test_resolve_team(self, tmp_path) -> None:
        assert resolve_team("tour_patrol").name == "tour_patrol"
        with pytest.raises(PolicyError, match="unknown policy"):
            resolve_team("nope")
        with pytest.raises(FileNotFoundError):
            resolve_team(str(tmp_path / "missing"))
        (tmp_path / "file.zip").write_text("x")
        with pytest.raises(PolicyError, match="is a file"):
            resolve_team(str(tmp_path / "file.zip"))
