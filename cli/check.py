"""``rig check --config rig.yaml [--seconds N]``: bring-up check of the rig's cameras.

Opens both cameras of the config for N seconds through the service's capture path and prints a
pass/fail table a technician can act on, 80 columns wide at least (:mod:`rig.bringup`;
docs/deployment.md, "Bring-up check"). Exit status: 0 when every check passes (warnings allowed),
1 when a check failed or could not be measured, 2 for bad input (config, calibration, option).
"""

from __future__ import annotations

from typing import Annotated

import typer
from rich import box
from rich.markup import escape
from rich.table import Table

from calibration import load_rig
from cli.console import console, progress_bar
from cli.errors import fail
from cli.serve import ServiceConfigOption
from rig.bringup import NOT_MEASURED, BringupReport, run_bringup
from rig.capture.capture import CAMERA_NAMES

__all__ = ["CHECK_FAILED", "register"]

#: Exit status when a check failed (bad input is 2, as everywhere).
CHECK_FAILED = 1
_STYLE = {"pass": "green", "warn": "yellow", "fail": "bold red", "n/a": "dim", NOT_MEASURED: "yellow"}


def _table(report: BringupReport) -> Table:
    """Four columns that fit 80 terminal columns: the check with its camera, what was measured
    (and, below it, what to do), the limit, the result."""
    table = Table(
        title=f"rig check: {report.seconds:g} s, {report.pairs} pairs taken",
        box=box.SQUARE,
        padding=(0, 1),
        expand=False,
    )
    table.add_column("check", no_wrap=True)
    table.add_column("measured", ratio=3, overflow="fold")
    table.add_column("expected", ratio=2, overflow="fold")
    table.add_column("result", no_wrap=True)
    for r in report.rows:
        measured = escape(r.value) + (f"\n[dim]→ {escape(r.action)}[/]" if r.action else "")
        check = f"{r.check} {r.camera}".strip()
        table.add_row(check, measured, escape(r.expected), f"[{_STYLE[r.result]}]{r.result}[/]")
    return table


def _summary(report: BringupReport, calibration: object) -> str:
    rows, failed, unmeasured = report.rows, report.failed, report.not_measured
    counted = [r for r in rows if r.result != "n/a"]
    not_measured = f"; {len(unmeasured)} not measured (no frame)" if unmeasured else ""
    if failed:
        names = ", ".join(escape(f"{r.check} {r.camera}".strip()) for r in failed)
        return f"[bold red]{len(failed)} of {len(counted)} checks failed[/]: {names}{not_measured}"
    passed = len(counted) - len(unmeasured)
    if unmeasured:
        return f"[yellow]{passed} of {len(counted)} checks passed[/]{not_measured}"
    na = len(rows) - len(counted)
    apply = f", {na} do not apply" if na else ""
    return f"[green]all {passed} checks passed[/]{apply} (calibration {escape(str(calibration))})"


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
        Exit status 0: all pass; 1: a check failed or got no frame to measure; 2: bad input.
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
        console.print(_summary(report, calibration), highlight=False)
        if report.failed or report.not_measured:
            raise typer.Exit(CHECK_FAILED)
