"""The ``rig`` console command: the Typer app with one module per command group.

Errors from every command go through :mod:`cli.errors` (one line on stderr, exit status 2 for bad
input); ``-h``/``--help`` works on every command, ``--version`` on the root.

A command's module is imported when the command is looked up (:class:`LazyCommands`): ``rig
process`` imports what processing needs, not the service, the calibration solvers or the
renderer; only ``rig -h``, which lists every command, imports them all.
"""

from __future__ import annotations

from collections.abc import Iterator, MutableMapping
from importlib import import_module
from importlib.metadata import PackageNotFoundError, version
from typing import Annotated, Any

import typer
from typer.main import get_group

from cli.console import exit_on_broken_pipe
from cli.errors import MappedErrorsGroup

__all__ = ["COMMANDS", "DISTRIBUTION", "LazyCommands", "build_app", "main", "package_version"]

DISTRIBUTION = "odfc-rig"
#: Each command (or command group) and the module that registers it, in the order ``rig -h``
#: lists them.
COMMANDS = {
    "serve": "cli.serve",
    "process": "cli.process",
    "record": "cli.record",
    "export": "cli.export",
    "check": "cli.check",
    "devices": "cli.devices",
    "calibrate": "cli.calibrate",
    "lut": "cli.lut",
    "sim": "cli.sim",
    "evaluate": "cli.evaluate",
}


def _commands_of(module_name: str) -> dict[str, Any]:
    """The click commands a module's ``register(app)`` adds."""
    module = import_module(module_name)
    app = typer.Typer()
    module.register(app)
    app.callback()(lambda: None)  # a group even for one command
    return dict(get_group(app).commands)


class LazyCommands(MutableMapping[str, Any]):
    """The root group's commands by name, each module imported on its first lookup."""

    def __init__(self, table: dict[str, str]) -> None:
        self._table = dict(table)
        self._loaded: dict[str, Any] = {}

    def __getitem__(self, name: str) -> Any:
        if name not in self._loaded:
            self._loaded.update(_commands_of(self._table[name]))
        return self._loaded[name]

    def __setitem__(self, name: str, command: Any) -> None:
        self._loaded[name] = command
        self._table.setdefault(name, "")

    def __delitem__(self, name: str) -> None:
        del self._table[name]
        self._loaded.pop(name, None)

    def __iter__(self) -> Iterator[str]:
        return iter(self._table)

    def __len__(self) -> int:
        return len(self._table)


class RigGroup(MappedErrorsGroup):
    """The root group: errors mapped (:class:`MappedErrorsGroup`), commands loaded lazily."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.commands = LazyCommands(COMMANDS)


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
        cls=RigGroup,
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

    return app


def main() -> None:
    try:
        build_app()(prog_name="rig")
    except BrokenPipeError:  # raised outside a command (typer's help, --version): as inside one
        exit_on_broken_pipe()


if __name__ == "__main__":
    main()
