"""What a config key is: :class:`Key` (its kind, default, range and meaning) and :class:`Section`
(a group of keys and where a config writes them). :mod:`sb3_pm.zoo.schema` lists the keys."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

#: Value kinds: ``int``, ``float``, ``bool``, ``str``, ``schedule`` (a number or ``lin_<number>``),
#: ``mapping``, ``list``, ``reward`` (a preset name or ``{term: weight}``), ``any`` (not checked
#: beyond ``null``), and the team's own ``deploy_temperature`` and ``deploy_filter``.
KINDS = (
    "int",
    "float",
    "bool",
    "str",
    "schedule",
    "mapping",
    "list",
    "reward",
    "any",
    "deploy_temperature",
    "deploy_filter",
)


@dataclass(frozen=True)
class Key:
    """One config key.

    :param name: as a config writes it.
    :param kind: one of :data:`KINDS`.
    :param default: the value that applies when the key is left out (documentation, see the module
        docstring), or a phrase in ``default_text``.
    :param help: one line for the docs table.
    :param choices: the allowed values of a ``str`` key (empty: any string).
    :param low: the smallest allowed number (``low_open``: excluded); ``None``: no lower bound.
    :param high: the largest allowed number (``high_open``: excluded); ``None``: no upper bound.
    :param nullable: ``null`` is allowed.
    :param algos: the algorithms that take it (empty: every one).
    :param default_text: the default as the docs table writes it, where ``default`` cannot say it.
    :param expects: what an error says a ``str`` key expected (empty: its choices, or a name).
    """

    name: str
    kind: str
    default: Any
    help: str
    choices: tuple[Any, ...] = ()
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    nullable: bool = False
    algos: tuple[str, ...] = ()
    default_text: str = ""
    expects: str = ""

    def __post_init__(self) -> None:
        if self.kind not in KINDS:  # a typo in this file, caught on import
            raise ValueError(f"key {self.name!r}: unknown kind {self.kind!r}")

    def range_text(self) -> str:
        """The allowed values, as the docs table and the errors write them (``>= 1``, ``(0, 1]``)."""
        if self.choices:
            text = ", ".join(f"{choice}" for choice in self.choices)
        elif self.low is not None and self.high is not None:
            left, right = "(" if self.low_open else "[", ")" if self.high_open else "]"
            text = f"{left}{self.low:g}, {self.high:g}{right}"
        elif self.low is not None:
            text = f"{'>' if self.low_open else '>='} {self.low:g}"
        elif self.high is not None:
            text = f"{'<' if self.high_open else '<='} {self.high:g}"
        else:
            text = ""
        if self.nullable:
            text = f"{text} or null" if text else "null allowed"
        return text


@dataclass(frozen=True)
class Section:
    """A group of keys: where a config writes them and the docs table that lists them
    (:mod:`sb3_pm.zoo.schema_doc`)."""

    name: str
    title: str
    #: ``entry`` (top level of an entry), ``policy_kwargs``, ``env_kwargs`` or ``reward``.
    where: str
    keys: tuple[Key, ...]
    #: Only this policy takes the section's keys (empty: every policy).
    policy: str = ""

    def names(self) -> tuple[str, ...]:
        return tuple(key.name for key in self.keys)


__all__ = ["KINDS", "Key", "Section"]
