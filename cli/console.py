"""What the ``rig`` command prints: the two consoles, warnings, one-line messages and progress bars.

Results go to stdout (``console``); progress, warnings and errors to stderr (``err_console``), so
``rig ... > file`` keeps the result alone.
"""

from __future__ import annotations

import os
import sys
from typing import NoReturn

from rich.console import Console
from rich.markup import escape
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    ProgressColumn,
    SpinnerColumn,
    Task,
    TextColumn,
    TimeElapsedColumn,
)
from rich.text import Text

__all__ = [
    "BROKEN_PIPE",
    "RateColumn",
    "console",
    "err_console",
    "exit_on_broken_pipe",
    "one_line",
    "progress_bar",
    "warn",
]

console = Console()
err_console = Console(stderr=True)
#: Exit status when the reader of stdout went away (``rig ... | head``): rich's own.
BROKEN_PIPE = 1


def exit_on_broken_pipe() -> NoReturn:
    """End quietly when stdout's reader has gone (``rig export mcap --help | head``): Python's
    documented way (stdout pointed at /dev/null, so the interpreter's last flush cannot fail
    again), as rich does for what it prints itself."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass  # no stdout file descriptor (embedded): nothing left to flush into the pipe
    finally:
        os.close(devnull)
    raise SystemExit(BROKEN_PIPE)


def one_line(message: object) -> str:
    """``message`` with every run of whitespace (newlines included) collapsed to one space, and
    escaped so that brackets in it (``[left]``, a path) print as they are, not as rich markup."""
    return escape(" ".join(str(message).split()))


def warn(message: str) -> None:
    """``warning: message`` on stderr (the command goes on)."""
    err_console.print(f"[yellow]warning:[/yellow] {one_line(message)}", highlight=False, soft_wrap=True)


def progress_bar(
    *columns: ProgressColumn, transient: bool = True, on_stdout: bool = False, disable: bool = False
) -> Progress:
    """A rich progress bar: spinner, description, bar, done/total and elapsed time, then
    ``columns``. On stderr unless ``on_stdout``; ``transient`` bars vanish when done."""
    return Progress(
        SpinnerColumn(),
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        *columns,
        console=console if on_stdout else err_console,
        transient=transient,
        disable=disable,
    )


class RateColumn(ProgressColumn):
    """How many ``unit`` per second the task advances (rich's estimate over the last 30 s)."""

    def __init__(self, unit: str) -> None:
        super().__init__()
        self.unit = unit

    def render(self, task: Task) -> Text:
        speed = task.finished_speed or task.speed
        shown = "-" if speed is None else f"{speed:.1f}"
        return Text(f"{shown} {self.unit}/s", style="progress.data.speed")
