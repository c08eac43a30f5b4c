"""The command line: parse arguments, render with Rich, map errors to exit codes — nothing else."""

from __future__ import annotations

import sys
from typing import Annotated

import typer

from stereogeo_cli import __version__
from stereogeo_cli.errors import StereoGeoError

app = typer.Typer(
    name="stereogeo",
    help="Calibrate a stereo camera from one image pair, with no calibration pattern.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def _version(value: bool) -> None:
    if value:
        typer.echo(f"stereogeo {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: Annotated[
        bool,
        typer.Option("--version", callback=_version, is_eager=True, help="Print the version and exit."),
    ] = False,
) -> None:
    """Calibrate a stereo camera from one image pair, with no calibration pattern."""


def fail(error: StereoGeoError) -> typer.Exit:
    """Print a one-line error on stderr and return the exit to raise."""
    typer.echo(f"error: {error}", err=True)
    return typer.Exit(code=error.exit_code)


def main() -> None:
    try:
        app()
    except StereoGeoError as error:  # raised outside a command body (e.g. while importing a plugin)
        typer.echo(f"error: {error}", err=True)
        sys.exit(error.exit_code)
