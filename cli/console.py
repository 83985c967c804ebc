"""Shared pieces of the ``rig`` command line: consoles, one-line failures, stubs."""

from __future__ import annotations

from typing import NoReturn

import typer
from rich.console import Console

__all__ = ["STUB_SETTINGS", "console", "err_console", "fail", "not_ready"]

console = Console()
err_console = Console(stderr=True)

# Stub commands accept whatever arguments the finished command will take.
STUB_SETTINGS = {"allow_extra_args": True, "ignore_unknown_options": True}


def fail(message: str, code: int = 2) -> NoReturn:
    """Print ``error: message`` as one line on stderr and exit (2 = bad input)."""
    err_console.print(f"[red]error:[/red] {' '.join(str(message).split())}", highlight=False, soft_wrap=True)
    raise typer.Exit(code)


def not_ready(command: str, issue: int) -> NoReturn:
    fail(f"'rig {command}' is not implemented yet (issue #{issue})")
