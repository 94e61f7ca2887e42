"""Entry point of the ``farfield`` command: a click group whose subcommands live in sibling modules.

Every :class:`farfield.core.errors.FarfieldError` (and a few well-known user mistakes) becomes one line on
stderr and the exit code from :data:`farfield.core.errors.ErrorKind`; a traceback means a bug in farfield
(an uncaught exception, or a :class:`farfield.core.errors.InternalError`, which exits 1 like one).
"""

from __future__ import annotations

import sys
import traceback
import warnings

import click

from farfield.core import __version__
from farfield.core.errors import ErrorKind, FarfieldError


class FarfieldGroup(click.Group):
    """A click group that reports farfield errors as one line and a non-zero exit code."""

    def invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except FarfieldError as error:
            if error.kind is ErrorKind.INTERNAL:  # a bug: the traceback is for the report
                traceback.print_exc()
                click.echo(f"farfield: internal error (a bug in farfield): {error}", err=True)
            else:
                click.echo(f"farfield: error: {error}", err=True)
            sys.exit(error.kind.exit_code)


@click.group(cls=FarfieldGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="farfield")
def cli() -> None:
    """farfield: bake impostors (image-based stand-ins) for distant 3D geometry."""


def _register() -> None:
    from farfield.cli import (
        bake_cmd,
        calibrate_cmd,
        client_cmds,
        evaluate_cmd,
        glb_cmd,
        inspect_cmd,
        layers_cmd,
        lookup_cmd,
        place_cmd,
        service_cmds,
        techniques_cmd,
        walkthrough_cmd,
    )

    cli.add_command(inspect_cmd.inspect)
    cli.add_command(layers_cmd.layers)
    cli.add_command(bake_cmd.bake)
    cli.add_command(techniques_cmd.techniques)
    cli.add_command(evaluate_cmd.evaluate)
    cli.add_command(service_cmds.up)
    cli.add_command(service_cmds.worker)
    cli.add_command(service_cmds.keys)
    cli.add_command(client_cmds.submit)
    cli.add_command(client_cmds.jobs)
    cli.add_command(client_cmds.scenes)
    cli.add_command(walkthrough_cmd.walkthrough_cmd)
    cli.add_command(place_cmd.place_cmd)
    cli.add_command(lookup_cmd.lookup_cmd)
    cli.add_command(calibrate_cmd.calibrate_cmd)
    cli.add_command(glb_cmd.glb_cmd)


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """A scene's warnings (a missing texture, dropped triangles) as one ``farfield: warning:`` line
    each on stderr, not Python's warning format with a source line of farfield; others as Python shows them."""
    from farfield.core.scene import SceneWarning

    if issubclass(category, SceneWarning):
        click.echo(f"farfield: warning: {message}", err=True)
    else:
        _PYTHON_SHOW_WARNING(message, category, filename, lineno, file, line)


_PYTHON_SHOW_WARNING = warnings.showwarning


def main(argv: list[str] | None = None) -> None:
    """Run the CLI (the ``farfield`` console script)."""
    warnings.showwarning = _show_warning
    try:  # techniques of FARFIELD_TECHNIQUE_MODULES, registered before the commands list the techniques
        from farfield.service.settings import load_technique_modules

        load_technique_modules()
    except FarfieldError as error:
        click.echo(f"farfield: error: {error}", err=True)
        sys.exit(error.kind.exit_code)
    _register()
    cli.main(args=argv, prog_name="farfield")


if __name__ == "__main__":
    main()
