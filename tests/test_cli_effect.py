"""``sb3-pm effect``: paired figures from saved evaluation records, and one-line errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from sb3_pm.cli import main
from sb3_pm.evaluation import EpisodeRecord, EvaluationResult


def write_record(
    path: Path, policy: str, graph: str, seed: int, values: list[float], caps: list[bool]
) -> Path:
    """An evaluation record of ``len(values)`` episodes with env seeds ``seed + e``."""
    episodes = [
        EpisodeRecord(
            e,
            seed + e,
            7,
            {"avg_uncertainty": v, "max_neglect": 2 * v, "saturated_fraction": 0.1 * c},
            np.zeros(0),
        )
        for e, (v, c) in enumerate(zip(values, caps))
    ]
    config = {"policy": policy, "graph": graph, "seed": seed}
    path.write_text(json.dumps(EvaluationResult(policy, graph, config, episodes).to_dict()))
    return path


def run_cli(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_paired_figures_match_scipy(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rng = np.random.default_rng(0)
    ours = {s: list(rng.uniform(50, 150, 5)) for s in (0, 1000)}
    theirs = {s: list(rng.uniform(80, 120, 5)) for s in (0, 1000)}
    policy = [
        write_record(tmp_path / f"a{s}.json", "team", "g", s, ours[s], [True] * 2 + [False] * 3) for s in ours
    ]
    reference = [
        write_record(tmp_path / f"b{s}.json", "grazing", "g", s, theirs[s], [False] * 5) for s in theirs
    ]
    out_json = tmp_path / "figures.json"
    code, out, _ = run_cli(
        capsys,
        "effect",
        "--policy",
        *map(str, policy),
        "--reference",
        *map(str, reference),
        "--json",
        str(out_json),
    )
    assert code == 0
    a, b = np.concatenate(list(ours.values())), np.concatenate(list(theirs.values()))
    test = stats.ttest_rel(a, b)
    runs = stats.ttest_rel([np.mean(v) for v in ours.values()], [np.mean(v) for v in theirs.values()])
    low, high = test.confidence_interval(0.95)
    assert f"difference {a.mean() - b.mean():+.1f} [{low:.1f}, {high:.1f}]" in out
    assert f"p (episodes) {test.pvalue:.2g}" in out and f"p (runs) {runs.pvalue:.2g}" in out
    assert "paired by episode seed" in out
    assert f"p90 {np.percentile(a, 90):.1f}" in out and "at the cap 4/10" in out and "at the cap 0/10" in out
    payload = json.loads(out_json.read_text())
    figures = payload["graphs"]
    assert figures[0]["effect"]["paired"] and figures[0]["policy"]["at_cap"] == 4
    assert figures[0]["policy"]["max_neglect"] == pytest.approx(2 * a.mean())
    # Over runs: each run's mean divided by the reference's mean over its runs (two runs each).
    scale = np.mean([np.mean(v) for v in theirs.values()])
    run_means = sorted(np.mean(v) / scale for v in ours.values())
    assert payload["runs"]["runs"] == 2 and payload["runs"]["iqm"] == pytest.approx(np.mean(run_means))
    assert f"IQM {np.mean(run_means):.3f}" in out and "P(better than the reference)" in out


def test_different_episodes_fall_back_to_welch(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    policy = write_record(tmp_path / "a.json", "team", "g", 0, [1.0, 2.0, 3.0], [False] * 3)
    reference = write_record(tmp_path / "b.json", "grazing", "g", 50, [2.0, 3.0, 5.0], [False] * 3)
    code, out, _ = run_cli(capsys, "effect", "--policy", str(policy), "--reference", str(reference))
    welch = stats.ttest_ind([1.0, 2.0, 3.0], [2.0, 3.0, 5.0], equal_var=False)
    assert code == 0 and "Welch" in out and f"p (episodes) {welch.pvalue:.2g}" in out


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (None, "does not exist"),
        ("{not json", "is not valid JSON"),
        ('{"mean": {}}', "no 'episodes' list"),
        ('{"episodes": [{"episode": 0}], "config": {}}', "names no graph and policy"),
    ],
)
def test_bad_records_get_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], content, message
) -> None:
    bad = tmp_path / "bad.json"
    if content is not None:
        bad.write_text(content)
    good = write_record(tmp_path / "good.json", "grazing", "g", 0, [1.0, 2.0], [False, False])
    code, _, err = run_cli(capsys, "effect", "--policy", str(bad), "--reference", str(good))
    assert code == 2 and message in err and "bad.json" in err and len(err.strip().splitlines()) == 1


def test_unknown_metric_and_disjoint_graphs(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    a = write_record(tmp_path / "a.json", "team", "g", 0, [1.0, 2.0], [False, False])
    b = write_record(tmp_path / "b.json", "grazing", "h", 0, [1.0, 2.0], [False, False])
    code, _, err = run_cli(capsys, "effect", "--policy", str(a), "--reference", str(a), "--metric", "speed")
    assert code == 2 and "--metric 'speed'" in err and "avg_uncertainty" in err
    code, _, err = run_cli(capsys, "effect", "--policy", str(a), "--reference", str(b))
    assert code == 2 and "share no graph" in err
