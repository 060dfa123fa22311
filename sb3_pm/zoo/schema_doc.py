"""``docs/CONFIG.md``'s key tables, generated from :mod:`sb3_pm.zoo.schema`.

CONFIG.md holds each section's table between ``<!-- schema:<section> -->`` and
``<!-- /schema:<section> -->``; ``tests/test_config_schema.py`` fails when they differ from what
the schema generates::

    python -m sb3_pm.zoo.schema_doc                         # print the tables
    python -m sb3_pm.zoo.schema_doc --write docs/CONFIG.md  # refresh them in CONFIG.md
"""

from __future__ import annotations

import sys
from pathlib import Path

from sb3_pm.files import write_atomic
from sb3_pm.zoo.schema import EXPERIMENT_SECTIONS, SECTIONS, Key, Section


def _default_text(key: Key) -> str:
    if key.default_text:
        return key.default_text
    if key.default is None:
        return "`null`" if key.nullable else "none"
    value = key.default
    if isinstance(value, bool):
        return f"`{str(value).lower()}`"
    if isinstance(value, float) and value != 0 and abs(value) < 1e-2:
        return f"`{value:.0e}`".replace("e-0", "e-")  # 3e-4, as configs write it
    return f"`{value}`"


def markdown_table(section: Section) -> str:
    """The docs table of ``section``: key, type, default, allowed values, meaning."""
    lines = ["| key | type | default | allowed | meaning |", "|---|---|---|---|---|"]
    for key in section.keys:
        kind = {"deploy_temperature": "float", "deploy_filter": "mapping"}.get(key.kind, key.kind)
        default = "(a weight)" if section.where == "reward" else _default_text(key)
        if default == "none" and section.where == "experiment":
            default = "required"
        allowed = key.range_text()
        lines.append(f"| `{key.name}` | {kind} | {default} | {allowed} | {key.help} |")
    return "\n".join(lines)


def _markers(section: Section) -> tuple[str, str]:
    return f"<!-- schema:{section.name} -->", f"<!-- /schema:{section.name} -->"


def render_doc(text: str) -> str:
    """``text`` (docs/CONFIG.md) with every section's table, between its markers, as the schema
    generates it.

    :raises ValueError: for a section whose markers are missing.
    """
    for section in SECTIONS + EXPERIMENT_SECTIONS:
        begin, end = _markers(section)
        head, found, rest = text.partition(begin)
        _, found_end, tail = rest.partition(end)
        if not found or not found_end:
            raise ValueError(f"no {begin} ... {end} markers")
        # The policy's four tables share one heading in CONFIG.md: each says which part it is.
        title = f"**{section.title}**\n\n" if section.where == "policy_kwargs" else ""
        text = f"{head}{begin}\n{title}{markdown_table(section)}\n{end}{tail}"
    return text


def main(argv: list[str]) -> int:
    """Print the tables, or (``--write FILE``) refresh them in ``FILE``."""
    if argv[:1] == ["--write"] and len(argv) == 2:
        path = Path(argv[1])
        write_atomic(path, render_doc(path.read_text()))
        return 0
    for section in SECTIONS + EXPERIMENT_SECTIONS:
        print(f"### {section.title}\n\n{markdown_table(section)}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))


__all__ = ["main", "markdown_table", "render_doc"]
