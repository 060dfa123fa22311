"""The errors a user can fix, as the project's own types.

The command line prints an :class:`Sb3PmError` (and an ``OSError``: an unwritable path, a missing
file, a full disk) as one line naming the problem, and exits with status 2. Anything else is a bug
and keeps its traceback. Errors about a value also derive from ``ValueError``, so Python callers
that catch ``ValueError`` keep working.

This module depends on nothing else in the package, so every layer can raise these.
"""

from __future__ import annotations


class Sb3PmError(Exception):
    """Base of every error that names a problem in the user's input, which the user can fix."""


class UsageError(Sb3PmError):
    """A bad command-line flag or combination of flags."""


class InputError(Sb3PmError, ValueError):
    """A value given to the library that it cannot use (the message names it and says why)."""


__all__ = ["InputError", "Sb3PmError", "UsageError"]
