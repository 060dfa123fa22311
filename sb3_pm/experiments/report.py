"""``DIR/report.md``: one self-contained Markdown page per sweep, written by the runner.

It gathers what the sweep's other files hold (command, protocol, the aggregates over training
runs, pooled table, ANOVA, per-graph table, effects against the reference algorithm, figures)
with the code version and the compute the cells took, so that a results document can quote it as it is.
"""

from __future__ import annotations

import json
import subprocess
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from sb3_pm.files import write_atomic
from sb3_pm.version import __version__

FIGURES = {
    "performance_profile.png": "Performance profiles over training runs (normalized by the reference)",
    "uncertainty.png": "Summed target uncertainty over an evaluation episode (mean over episodes)",
    "training.png": "Training curves: episode avg_uncertainty per learner timestep",
    "estimator_loss.png": "Estimator loss during training",
    "table.png": "Avg. uncertainty per algorithm",
}


def code_version() -> str:
    """``sb3_pm <version>``, plus the git commit (and ``+dirty``) when run from a git checkout."""
    here = Path(__file__).resolve().parent
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=here, capture_output=True, text=True, timeout=10
        )
        status = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=here,
            capture_output=True,
            text=True,
            timeout=10,
        )
    except (OSError, subprocess.SubprocessError):  # no git: the package version is all we know
        return f"sb3_pm {__version__}"
    if commit.returncode != 0:
        return f"sb3_pm {__version__}"
    dirty = "+dirty" if status.returncode == 0 and status.stdout.strip() else ""
    return f"sb3_pm {__version__}, git {commit.stdout.strip()}{dirty}"


def _cell_seconds(cells: Sequence[Any]) -> tuple[float, int]:
    """Summed wall-clock seconds of the cells (as each recorded it) and how many recorded it."""
    total, counted = 0.0, 0
    for cell in cells:
        path = Path(cell.folder) / "evaluation.json"
        seconds = json.loads(path.read_text()).get("cell", {}).get("seconds") if path.exists() else None
        if seconds is not None:
            total, counted = total + float(seconds), counted + 1
    return total, counted


def _variant_budgets(record: dict[str, Any]) -> str:
    """``"; variant X: N steps per learner"`` for each learned variant that sets its own budget."""
    own = [
        f"; variant `{key}`: {variant['timesteps']} steps per learner"
        for key, variant in (record.get("variants") or {}).items()
        if isinstance(variant, dict) and variant.get("timesteps")
    ]
    return "".join(own)


def write_report(out: Path, record: dict[str, Any], cells: Sequence[Any], reference: str) -> Path:
    """Write ``out/report.md`` from the files the runner has already written into ``out``.

    :param record: the experiment as run (``experiment_record``).
    :param cells: every cell of the sweep (for the compute they recorded).
    :param reference: the algorithm of ``effects.md``.
    """
    command = (out / "command.txt").read_text().strip()
    seconds, counted = _cell_seconds(cells)
    budget = record.get("timesteps")
    lines = [
        f"# {record['name']}",
        "",
        "```bash",
        command,
        "```",
        "",
        f"- graphs: {', '.join(Path(g).name for g in record['graphs'])}",
        f"- training seeds: {', '.join(map(str, record['seeds']))}; "
        f"{record['episodes']} evaluation episodes of {record['max_cycles']} steps per (graph, seed), "
        f"{record['n_agents']} agents; evaluation env seeds {record['evaluation_seeds']}",
        "- training budget: "
        + (f"{budget} steps per learner" if budget else "the config's `n_timesteps`")
        + (f" (config `{record['config']}`)" if record.get("config") else "")
        + _variant_budgets(record),
        f"- code that wrote this report: {code_version()} (each cell's evaluation.json records the code "
        "that ran it)",
        f"- compute: {seconds / 3600:.2f} h summed over {counted} cells (training + evaluation, "
        "as each cell recorded it)",
        "",
        "## Across training runs",
        "",
        (out / "runs.md").read_text().strip(),
        "",
        "## Table (every graph, seed and episode pooled)",
        "",
        (out / "results.md").read_text().strip(),
        "",
        "One-way ANOVA across the algorithms, on pooled episodes (the paper's Table I test; episodes "
        "of one trained team are not independent replicates of training, so the run statistics "
        "above and the per-run p-values below are the ones to trust for training changes):",
        "",
        "```",
        (out / "anova.txt").read_text().strip(),
        "```",
        "",
        "## Per graph",
        "",
        (out / "by_graph.md").read_text().strip(),
        "",
        f"## Differences from {reference}",
        "",
        (out / "effects.md").read_text().strip(),
        "",
        "## Figures",
        "",
    ]
    for name, caption in FIGURES.items():
        if (out / name).exists():
            lines += [f"![{caption}]({name})", ""]
    path = out / "report.md"
    write_atomic(path, "\n".join(lines))
    return path
