"""The ``rig`` command's one error mapping: every exception a command raises becomes one line on
stderr and an exit status, here and nowhere else.

* :class:`CommandError` (raised by :func:`fail`), ``CalibrationError``, ``RigError``,
  ``ServiceError``: ``error: <message>``, exit status 2 (bad input or a faulty device);
* ``KeyboardInterrupt``: ``interrupted``, exit status 130;
* ``BrokenPipeError`` (stdout's reader went away: ``rig ... | head``): nothing, exit status 1;
* anything else (a bug): ``internal error: <type>: <message> (run with RIG_DEBUG=1 ...)``, 1.

With ``RIG_DEBUG=1`` nothing is mapped: the exception propagates with its traceback. Commands
never print an error and exit themselves: they raise.
"""

from __future__ import annotations

import os
from typing import Any, NoReturn

import typer
from typer.core import TyperGroup
from typer.exceptions import TyperException

from calibration.errors import CalibrationError
from cli.console import err_console, exit_on_broken_pipe, one_line
from rig.errors import RigError
from service.errors import ServiceError

__all__ = [
    "BAD_INPUT",
    "INTERNAL_ERROR",
    "INTERRUPTED",
    "CommandError",
    "MappedErrorsGroup",
    "exit_status",
    "fail",
    "report",
]

BAD_INPUT = 2
INTERNAL_ERROR = 1
INTERRUPTED = 130

#: Exceptions that mean "bad input or a faulty device": the user can fix them.
PROJECT_ERRORS: tuple[type[Exception], ...] = (CalibrationError, RigError, ServiceError)


class CommandError(Exception):
    """The command cannot do what it was asked: an option value out of range, options that
    exclude each other, nothing usable in its input."""


def fail(message: str) -> NoReturn:
    """Refuse the command: raises :class:`CommandError` (one line, exit status 2)."""
    raise CommandError(message)


def exit_status(err: BaseException) -> int:
    """The exit status ``err`` maps to."""
    if isinstance(err, (CommandError, *PROJECT_ERRORS)):
        return BAD_INPUT
    if isinstance(err, KeyboardInterrupt):
        return INTERRUPTED
    return INTERNAL_ERROR


def report(err: BaseException) -> int:
    """Print the one line ``err`` maps to on stderr; returns its exit status."""
    status = exit_status(err)
    if status == BAD_INPUT:
        line = f"[red]error:[/red] {one_line(err)}"
    elif status == INTERRUPTED:
        line = "interrupted"
    else:
        line = (
            f"[red]internal error:[/red] {type(err).__name__}: {one_line(err)} "
            "(run with RIG_DEBUG=1 for the traceback)"
        )
    err_console.print(line, highlight=False, soft_wrap=True)
    return status


def debugging() -> bool:
    """RIG_DEBUG is set (and not 0): let exceptions through with their traceback."""
    return os.environ.get("RIG_DEBUG", "") not in ("", "0")


class MappedErrorsGroup(TyperGroup):
    """The root command group: whatever a command raises goes through :func:`report`, so the
    console script, ``python -m cli`` and an in-process ``CliRunner`` all end the same way."""

    # typer.Context is what typer hands in; the base class names the vendored click's Context.
    def invoke(self, ctx: typer.Context) -> Any:  # type: ignore[override]
        try:
            return super().invoke(ctx)
        except (TyperException, typer.Exit, typer.Abort):
            raise  # typer's own usage errors (with the usage line), --help, --version
        except BrokenPipeError:
            exit_on_broken_pipe()
        except (Exception, KeyboardInterrupt) as err:
            if debugging():
                raise
            raise typer.Exit(report(err)) from err
