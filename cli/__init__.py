"""The ``farfield`` command line: thin commands that call ``core`` and print text or ``--json``."""

from __future__ import annotations

from farfield.core.errors import FarfieldError


class ArgumentError(FarfieldError):
    """Command-line arguments that do not parse or do not go together (a malformed ``--bounds`` or
    ``--option``, ``--layers`` with ``--near-field``, a flag the chosen technique has no use for).
    Bad input (exit code 2): reported by :class:`farfield.cli.main.FarfieldGroup` as one line, like
    every :class:`~farfield.core.errors.FarfieldError`."""


def sides_option(command):
    """The ``--sides`` option (``one`` or ``both``, :mod:`farfield.core.sidedness`) of a command that
    loads a scene file: the sidedness of the objects of OBJ, PLY and STL, which state none."""
    import click

    from farfield.core.sidedness import DEFAULT_SIDES, SIDES, SIDES_HELP

    return click.option(
        "--sides",
        type=click.Choice(SIDES),
        default=DEFAULT_SIDES,
        show_default=True,
        help=SIDES_HELP[0].upper() + SIDES_HELP[1:] + ".",
    )(command)


def object_names(text: str | None) -> list[str] | None:
    """The names of ``--objects a,b`` (None without the option: every object).  An option that names
    no object (``--objects ""``, ``--objects ,``: a shell variable left empty) is bad input, not the
    whole scene, as ``"objects": []`` is a 422 over HTTP.

    >>> object_names(" a, b ,"), object_names(None)
    (['a', 'b'], None)
    """
    if text is None:
        return None
    names = [name.strip() for name in text.split(",") if name.strip()]
    if not names:
        raise ArgumentError(
            f"--objects {text!r} names no object: give comma-separated object names, or leave it out for all"
        )
    return names
