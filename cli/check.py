"""``rig check --config rig.yaml [--seconds N]``: bring-up check of the rig's cameras.

Opens both cameras of the config for N seconds through the service's capture path and prints a
pass/fail table a technician can act on (:mod:`rig.bringup`; docs/deployment.md, "Bring-up
check"). Exit status: 0 when every check passes (warnings allowed), 1 when a check failed, 2 for
bad input (config, calibration, option).
"""

from __future__ import annotations

from typing import Annotated

import typer
from rich.table import Table

from calibration import load_rig
from cli.console import console, progress_bar
from cli.errors import fail
from cli.serve import ServiceConfigOption
from rig.bringup import BringupReport, run_bringup
from rig.capture.capture import CAMERA_NAMES

__all__ = ["CHECK_FAILED", "register"]

#: Exit status when a check failed (bad input is 2, as everywhere).
CHECK_FAILED = 1
_STYLE = {"pass": "green", "warn": "yellow", "fail": "bold red", "n/a": "dim"}


def _table(report: BringupReport) -> Table:
    table = Table(title=f"rig check: {report.seconds:g} s, {report.pairs} pairs taken")
    for col in ("check", "camera", "measured", "expected", "result", "what to do"):
        table.add_column(col, overflow="fold")
    for r in report.rows:
        table.add_row(r.check, r.camera, r.value, r.expected, f"[{_STYLE[r.result]}]{r.result}[/]", r.action)
    return table


def register(app: typer.Typer) -> None:
    @app.command("check")
    def check(
        config: ServiceConfigOption = None,
        seconds: Annotated[
            float,
            typer.Option(
                "--seconds", "-s", metavar="N", min=1.0, max=600.0, help="How long to run the cameras (s)."
            ),
        ] = 5.0,
    ) -> None:
        """Open both cameras for N seconds and print a pass/fail table.

        Checks format, frame rate, timestamps, pairing skew, dropped and corrupt frames, USB
        bandwidth, exposure read back, calibration vs frame size and a sample rectified pair.
        Exit status 0: all pass; 1: a check failed; 2: bad input.
        """
        # The service's settings and calibration lookup (imported here: FastAPI is not needed).
        from service.runtime import resolve_calibration
        from service.settings import load_settings

        settings = load_settings(config)
        if settings.cameras is None:
            fail(f"{config or 'settings'}: field 'cameras' missing: rig check opens the configured cameras")
        calibration = resolve_calibration(settings)
        rig = load_rig(calibration)
        missing = [n for n in CAMERA_NAMES if n not in rig.cameras]
        if missing:
            fail(f"{calibration}: the rig has no camera {missing[0]!r} (has {', '.join(rig.names)})")
        with progress_bar() as bar:
            task = bar.add_task("cameras running", total=seconds)
            report = run_bringup(
                settings.cameras,
                rig,
                vpc=settings.rectified,
                stereo=settings.stereo,
                cache_dir=settings.cache_dir,
                seconds=seconds,
                on_tick=lambda t: bar.update(task, completed=t),
            )
        console.print(_table(report))
        failed = report.failed
        if failed:
            console.print(
                f"[bold red]{len(failed)} of {len(report.rows)} checks failed[/]: "
                + ", ".join(f"{r.check} {r.camera}".strip() for r in failed),
                highlight=False,
                soft_wrap=True,
            )
            raise typer.Exit(CHECK_FAILED)
        console.print(
            f"[green]all {len(report.rows)} checks passed[/] (calibration {calibration})", highlight=False
        )
