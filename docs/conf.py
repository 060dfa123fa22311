"""Sphinx configuration: the Markdown pages (MyST) and the API reference (autodoc, autosummary).

Build from the repository root, offline, with warnings as errors:

    python -m sphinx -W --keep-going -b html docs docs/_build/html
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the checkout's package, installed or not

from sb3_pm.version import __version__  # noqa: E402

project = "sb3_pm"
author = "the sb3_pm authors"
copyright = "2026, the sb3_pm authors"
version = release = __version__

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
]
source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store"]

# MyST: heading anchors for in-page and cross-page links (``[text](PAGE.md#a-heading)``).
myst_heading_anchors = 4
myst_enable_extensions = ["colon_fence"]

# The API reference: one page per module, generated at build time into docs/api/ (ignored by git),
# so that a new or moved module needs no edit here.
autosummary_generate = True
autosummary_imported_members = False
# A package's page documents what the package itself defines; the classes it re-exports are
# documented once, in the module that defines them (so every cross-reference has one target).
autodoc_default_options = {
    "members": True,
    "undoc-members": False,
    "show-inheritance": True,
    "ignore-module-all": True,
}
# Only this package's docstrings: a method inherited from Gymnasium or SB3 without its own
# docstring stays undocumented rather than carrying the other library's text.
autodoc_inherit_docstrings = False
# The optional extra ``benchmarl`` (sb3_pm.integrations.benchmarl_task) is not installed to build
# the site: its libraries are stood in for, so that module's page still comes from its docstrings.
autodoc_mock_imports = ["benchmarl", "tensordict", "torchrl"]
autodoc_member_order = "bysource"
autodoc_typehints = "description"
autodoc_typehints_format = "short"
# Type hints name classes from numpy, torch, gymnasium and SB3, whose documentation is not part of
# an offline build: they stay plain text instead of unresolved references.
nitpicky = False

html_theme = "alabaster"
html_static_path: list[str] = []
html_title = f"sb3_pm {release}"
