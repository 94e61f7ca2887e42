"""The ``farfield`` command line: thin commands that call ``core`` and print text or ``--json``."""

from __future__ import annotations

from farfield.core.errors import FarfieldError


class ArgumentError(FarfieldError):
    """Command-line arguments that do not parse or do not go together (a malformed ``--bounds`` or
    ``--option``, ``--layers`` with ``--near-field``, a flag the chosen technique has no use for).
    Bad input (exit code 2): reported by :class:`farfield.cli.main.FarfieldGroup` as one line, like
    every :class:`~farfield.core.errors.FarfieldError`."""
