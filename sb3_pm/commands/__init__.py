"""Subcommands of the ``sb3-pm`` CLI, one module each (see :mod:`sb3_pm.cli`)."""
