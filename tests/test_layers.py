"""Each layer of sb3_pm imports only from its own layer and the layers below it.

Every module of the package is parsed with :mod:`ast`, and every ``import``/``from ... import``
statement in it counts, wherever it stands: at the top, inside a function (a lazy import), under
``if TYPE_CHECKING:`` or in a ``try``. Imports by string (``importlib.import_module``, the lazy
name tables of the packages' ``__init__``, Gymnasium entry points, the zoo's ``"module:attr"``
registries) are not statements and are not checked here.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = "sb3_pm"
ROOT = Path(__file__).resolve().parent.parent / PACKAGE

#: The layers, bottom up. A module belongs to the layer of the longest entry that names it or one of
#: its packages; a module may import from its own layer and from the layers below it.
LAYERS: list[tuple[str, ...]] = [
    # utilities
    (
        "sb3_pm.errors",
        "sb3_pm.files",
        "sb3_pm.machine",
        "sb3_pm.plain_state",
        "sb3_pm.pretrained",  # the shipped teams' folders
        "sb3_pm.progress",
        "sb3_pm.version",
    ),
    ("sb3_pm.graphs",),
    ("sb3_pm.planning",),  # centralized plans, lower bounds and territory conventions, on the graph alone
    ("sb3_pm.envs",),  # the environment, with the mental maps it maintains
    ("sb3_pm.team_interface",),
    ("sb3_pm.policies", "sb3_pm.baselines"),
    ("sb3_pm.callbacks", "sb3_pm.ppo_dcbf"),
    ("sb3_pm.zoo",),
    # a team by job: how it acts and is stored, and the env bridge its learners train through ...
    ("sb3_pm.agents.deployment", "sb3_pm.agents.multiplexing"),
    # ... below the training of a team, one learner per agent or one shared network
    ("sb3_pm.agents", "sb3_pm.agents.training", "sb3_pm.sharing"),
    ("sb3_pm.evaluation",),
    # bridges to other MARL libraries: a task of theirs, their trained policies as teams
    ("sb3_pm.integrations",),
    ("sb3_pm.experiments",),
    # The top: the package itself (``import sb3_pm``), the Gymnasium registration it runs, and the
    # command line.
    ("sb3_pm", "sb3_pm.registration", "sb3_pm.commands", "sb3_pm.cli"),
]

#: Upward imports that exist today in modules this refactor could not edit, as
#: (importing module, imported module). To be removed: each entry goes when its import is fixed.
KNOWN_UPWARD: set[tuple[str, str]] = set()

LAYER_OF: dict[str, int] = {name: level for level, names in enumerate(LAYERS) for name in names}


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


MODULES: dict[str, Path] = {module_name(path): path for path in sorted(ROOT.rglob("*.py"))}


def layer_of(module: str) -> int | None:
    """The layer of ``module`` (a module or package of sb3_pm), ``None`` if no entry names it."""
    parts = module.split(".")
    for end in range(len(parts), 0, -1):
        level = LAYER_OF.get(".".join(parts[:end]))
        if level is not None:
            return level
    return None


def is_package(module: str) -> bool:
    return MODULES.get(module, Path()).name == "__init__.py"


def imported_modules(module: str, path: Path) -> list[tuple[int, str]]:
    """``(line, imported sb3_pm module)`` for every import statement of the file."""
    found: list[tuple[int, str]] = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative: resolved against this module's package
                base = module.split(".")
                if not is_package(module):
                    base.pop()
                base = base[: len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            for alias in node.names:
                # ``from package import submodule`` imports the submodule; anything else is a name
                # of ``target`` itself.
                submodule = f"{target}.{alias.name}"
                found.append((node.lineno, submodule if submodule in MODULES else target))
    ours = [(line, name) for line, name in found if name == PACKAGE or name.startswith(PACKAGE + ".")]
    return list(dict.fromkeys(ours))  # one entry per (line, module), in order


def upward_imports() -> list[tuple[tuple[str, str], str]]:
    """Every upward import statement: its ``(importer, imported)`` pair and a readable line."""
    found: list[tuple[tuple[str, str], str]] = []
    for module, path in MODULES.items():
        here = layer_of(module)
        assert here is not None, f"{module} is in no layer: add it to LAYERS"
        for line, imported in imported_modules(module, path):
            there = layer_of(imported)
            assert there is not None, f"{path}:{line} imports {imported}, which is in no layer"
            if there > here:
                where = f"{path.relative_to(ROOT.parent)}:{line}"
                text = f"{where}: {module} (layer {here}) imports {imported} (layer {there})"
                found.append(((module, imported), text))
    return found


def test_every_module_has_a_layer() -> None:
    assert MODULES, f"no modules found under {ROOT}"
    unplaced = sorted(module for module in MODULES if layer_of(module) is None)
    assert not unplaced, f"modules in no layer (add them to LAYERS): {unplaced}"


def test_no_upward_imports() -> None:
    new = [text for pair, text in upward_imports() if pair not in KNOWN_UPWARD]
    assert not new, "imports from a higher layer:\n" + "\n".join(new)


def test_known_upward_imports_still_exist() -> None:
    """An entry of KNOWN_UPWARD whose import is gone must leave the set, so it cannot come back."""
    stale = sorted(KNOWN_UPWARD - {pair for pair, _ in upward_imports()})
    assert not stale, f"fixed upward imports still listed in KNOWN_UPWARD, remove them: {stale}"


@pytest.mark.parametrize(
    ("module", "source", "expected"),
    [
        ("sb3_pm.envs.core", "from sb3_pm.graphs import GraphSpec", "sb3_pm.graphs"),
        ("sb3_pm.envs.core", "import sb3_pm.policies.layers", "sb3_pm.policies.layers"),
        (
            "sb3_pm.envs.core",
            "from sb3_pm.envs import persistent_monitoring_v0",
            "sb3_pm.envs.persistent_monitoring_v0",
        ),
        ("sb3_pm.envs.core", "from . import rendering", "sb3_pm.envs.rendering"),
        ("sb3_pm.envs.core", "from ..policies import layers", "sb3_pm.policies.layers"),
        ("sb3_pm.envs", "from .core import MonitoringCore", "sb3_pm.envs.core"),
        ("sb3_pm.envs.core", "import sb3_pm", "sb3_pm"),
    ],
)
def test_import_resolution(module: str, source: str, expected: str, tmp_path: Path) -> None:
    """Absolute, relative and ``from package import submodule`` statements name the right module,
    nested in a function or not."""
    path = tmp_path / "module.py"
    path.write_text(f"def f():\n    {source}\n", encoding="utf-8")
    assert [name for _, name in imported_modules(module, path)] == [expected]
