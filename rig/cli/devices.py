"""`rig devices` (issue #5)."""

from __future__ import annotations

import typer

from rig.cli.common import STUB_SETTINGS, not_ready

__all__ = ["register"]


def register(app: typer.Typer) -> None:
    @app.command("devices", context_settings=STUB_SETTINGS, help="Not implemented yet (issue #5).")
    def devices(ctx: typer.Context) -> None:
        not_ready("devices", 5)
