"""What the ``rig`` command prints: the two consoles, warnings, one-line messages and progress bars.

Results go to stdout (``console``); progress, warnings and errors to stderr (``err_console``), so
``rig ... > file`` keeps the result alone.
"""

from __future__ import annotations

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

__all__ = ["RateColumn", "console", "err_console", "one_line", "progress_bar", "warn"]

console = Console()
err_console = Console(stderr=True)


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
