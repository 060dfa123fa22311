"""Where the tests find the repository's configs and experiment files.

The experiment files a user runs ship in ``zoo/experiments/``; the research sweeps, which the tests
still load, are in ``research/experiments/`` (not installed).
"""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ZOO = ROOT / "zoo"
SHIPPED_EXPERIMENTS = ZOO / "experiments"
RESEARCH_EXPERIMENTS = ROOT / "research" / "experiments"


def experiment_file(name: str) -> Path:
    """The experiment file ``name`` (a stem): the shipped one, else the research sweep's."""
    shipped = SHIPPED_EXPERIMENTS / f"{name}.yml"
    return shipped if shipped.is_file() else RESEARCH_EXPERIMENTS / f"{name}.yml"


def every_experiment_file() -> list[Path]:
    """Every experiment file of the repository, shipped and research, sorted by name."""
    return sorted(
        [*SHIPPED_EXPERIMENTS.glob("*.yml"), *RESEARCH_EXPERIMENTS.glob("*.yml")], key=lambda p: p.stem
    )


def trains_config(path: Path, stem: str) -> bool:
    """Whether the experiment file's base training config is zoo/``stem``.yml."""
    text = path.read_text()
    return any(f"\nconfig: {prefix}{stem}.yml\n" in text for prefix in ("../", "../../zoo/"))


def trains_the_default(path: Path) -> bool:
    """Whether the experiment file's base training config is zoo/ippo.yml, today's default."""
    return trains_config(path, "ippo")


def trains_the_split_default(path: Path) -> bool:
    """Whether the experiment file's base training config is zoo/ippo_split.yml, the default before
    planned territories became paper-50's (the files measured on it train it by name)."""
    return trains_config(path, "ippo_split")
