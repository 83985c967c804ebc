"""`rig process` (issue #3)."""

from __future__ import annotations

import typer

from rig.cli.common import STUB_SETTINGS, not_ready

__all__ = ["register"]


def register(app: typer.Typer) -> None:
    @app.command("process", context_settings=STUB_SETTINGS, help="Not implemented yet (issue #3).")
    def process(ctx: typer.Context) -> None:
        not_ready("process", 3)
