"""Configs that ship with the package, found by name or by path.

The rl-zoo style training configs and the experiment files live in the repository's ``zoo/``
folder. The wheel carries the same files as ``sb3_pm/configs/`` (setup.cfg maps the package
``sb3_pm.configs`` to ``zoo/``); a checkout, or an editable install, reads ``zoo/`` itself. A user
may name one in three ways, tried in this order:

1. a path that exists (``zoo/ippo.yml`` from the repository root, ``~/my_config.yml``);
2. a shipped file by name, with or without ``.yml``: ``ippo``, ``ippo_paper.yml``, and for
   experiments ``comparison`` or ``experiments/comparison.yml``;
3. a repository path whose file is not there (``zoo/ippo.yml`` outside the repository): its
   shipped copy, so the README's commands work from any folder.
"""

from __future__ import annotations

from pathlib import Path

_PACKAGE_DIR = Path(__file__).resolve().parents[1]
#: Where the shipped configs are: ``sb3_pm/configs`` in an installed wheel, else the checkout's ``zoo/``.
CONFIG_DIR = (
    _PACKAGE_DIR / "configs" if (_PACKAGE_DIR / "configs").is_dir() else _PACKAGE_DIR.parent / "zoo"
)
#: Where the shipped experiment files are.
EXPERIMENT_DIR = CONFIG_DIR / "experiments"
#: The training config used when none is named: the best measured configuration.
DEFAULT_CONFIG = "ippo"


def shipped_names(folder: Path = CONFIG_DIR) -> list[str]:
    """The names (file stems) of the shipped ``.yml`` files in ``folder``, sorted."""
    return sorted(path.stem for path in folder.glob("*.yml"))


def _shipped(value: str, folder: Path, prefixes: tuple[str, ...]) -> Path | None:
    name = value
    for prefix in prefixes:
        if name.startswith(prefix):
            name = name[len(prefix) :]
            break
    if "/" in name or not name:
        return None
    for candidate in (folder / name, folder / f"{name}.yml"):
        if candidate.is_file():
            return candidate
    return None


def _resolve(value: str | Path, folder: Path, prefixes: tuple[str, ...], kind: str) -> Path:
    path = Path(value)
    if path.is_file():
        return path
    found = _shipped(str(value), folder, prefixes)
    if found is None:
        raise FileNotFoundError(
            f"{kind} file not found: {value} (shipped {kind}s: {', '.join(shipped_names(folder))})"
        )
    return found


def resolve_config_path(value: str | Path) -> Path:
    """The training config ``value`` names (see the module docstring for the rules).

    :raises FileNotFoundError: naming the value and the shipped configs, if nothing matches.
    """
    return _resolve(value, CONFIG_DIR, ("zoo/", "./zoo/"), "config")


def resolve_experiment_path(value: str | Path) -> Path:
    """The experiment file ``value`` names (see the module docstring for the rules).

    :raises FileNotFoundError: naming the value and the shipped experiments, if nothing matches.
    """
    return _resolve(
        value, EXPERIMENT_DIR, ("zoo/experiments/", "./zoo/experiments/", "experiments/"), "experiment"
    )
