"""`rig lut build|show` (issue #3)."""

from __future__ import annotations

import typer

from rig.cli.common import STUB_SETTINGS, not_ready

__all__ = ["register"]


def register(app: typer.Typer) -> None:
    lut = typer.Typer(help="Build and list cached VPC lookup tables.", no_args_is_help=True)

    @lut.command("build", context_settings=STUB_SETTINGS, help="Not implemented yet (issue #3).")
    def build(ctx: typer.Context) -> None:
        not_ready("lut build", 3)

    @lut.command("show", context_settings=STUB_SETTINGS, help="Not implemented yet (issue #3).")
    def show(ctx: typer.Context) -> None:
        not_ready("lut show", 3)

    app.add_typer(lut, name="lut")
