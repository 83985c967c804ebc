"""`rig evaluate` (issue #7)."""

from __future__ import annotations

import typer

from rig.cli.common import STUB_SETTINGS, not_ready

__all__ = ["register"]


def register(app: typer.Typer) -> None:
    @app.command("evaluate", context_settings=STUB_SETTINGS, help="Not implemented yet (issue #7).")
    def evaluate(ctx: typer.Context) -> None:
        not_ready("evaluate", 7)
