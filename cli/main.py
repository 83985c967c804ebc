"""The ``rig`` console command: the Typer app with one module per command group.

Errors from every command go through :mod:`cli.errors` (one line on stderr, exit status 2 for bad
input); ``-h``/``--help`` works on every command, ``--version`` on the root.
"""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version
from typing import Annotated

import typer

from cli import calibrate, check, devices, evaluate, export, lut, process, record, serve, sim
from cli.errors import MappedErrorsGroup

__all__ = ["DISTRIBUTION", "build_app", "main", "package_version"]

DISTRIBUTION = "odfc-rig"
#: Command groups in the order ``rig -h`` lists them.
COMMAND_MODULES = (serve, process, record, export, check, devices, calibrate, lut, sim, evaluate)


def package_version() -> str:
    try:
        return version(DISTRIBUTION)
    except PackageNotFoundError:  # run from a source tree that was never installed
        return "unknown (not installed)"


def _print_version(value: bool) -> None:
    if value:
        typer.echo(f"rig ({DISTRIBUTION}) {package_version()}")
        raise typer.Exit()


def build_app() -> typer.Typer:
    app = typer.Typer(
        name="rig",
        cls=MappedErrorsGroup,
        help="Depth service for an orthogonally divergent fisheye stereo rig.",
        no_args_is_help=True,
        pretty_exceptions_enable=False,
        add_completion=False,
        context_settings={"help_option_names": ["-h", "--help"]},
    )

    @app.callback()
    def root(
        show_version: Annotated[
            bool,
            typer.Option(
                "--version", is_eager=True, callback=_print_version, help="Print the version and exit."
            ),
        ] = False,
    ) -> None:
        """Depth service for an orthogonally divergent fisheye stereo rig."""

    for module in COMMAND_MODULES:
        module.register(app)
    return app


def main() -> None:
    build_app()(prog_name="rig")


if __name__ == "__main__":
    main()
