"""`rig calibrate intrinsics|stereo` (issue #4)."""

from __future__ import annotations

import typer

from rig.cli.common import STUB_SETTINGS, not_ready

__all__ = ["register"]


def register(app: typer.Typer) -> None:
    cal = typer.Typer(help="Calibrate cameras and the rig from target images.", no_args_is_help=True)

    @cal.command("intrinsics", context_settings=STUB_SETTINGS, help="Not implemented yet (issue #4).")
    def intrinsics(ctx: typer.Context) -> None:
        not_ready("calibrate intrinsics", 4)

    @cal.command("stereo", context_settings=STUB_SETTINGS, help="Not implemented yet (issue #4).")
    def stereo(ctx: typer.Context) -> None:
        not_ready("calibrate stereo", 4)

    app.add_typer(cal, name="calibrate")
