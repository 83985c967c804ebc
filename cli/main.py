"""The ``rig`` console command: ``serve`` plus the subcommands of ``rig.cli``.

Errors from the packages become one line on stderr and exit status 2; nothing reaches the user
as a traceback unless ``RIG_DEBUG=1``.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Annotated

import typer

from calibration.errors import CalibrationError
from rig.cli import register as register_rig_commands
from rig.cli.common import err_console
from rig.errors import RigError
from service.errors import ServiceError

__all__ = ["build_app", "main"]


def build_app() -> typer.Typer:
    app = typer.Typer(
        name="rig",
        help="Depth service for an orthogonally divergent fisheye stereo rig.",
        no_args_is_help=True,
        pretty_exceptions_enable=False,
        add_completion=False,
    )

    @app.command("serve")
    def serve(
        config: Annotated[
            Path | None,
            typer.Option(
                "--config", "-c", help="YAML config file (default: $RIG_CONFIG).", show_default=False
            ),
        ] = None,
        demo: Annotated[
            bool, typer.Option("--demo", help="Serve the built-in simulated rig (rendered once, cached).")
        ] = False,
        host: Annotated[
            str | None,
            typer.Option(help="Bind address (default 127.0.0.1); non-loopback needs RIG_API_TOKEN."),
        ] = None,
        port: Annotated[int | None, typer.Option(help="TCP port (default 8000); 0 = any free port.")] = None,
        recording: Annotated[
            Path | None, typer.Option("--recording", help="Serve a recording directory (looped).")
        ] = None,
        calibration: Annotated[
            Path | None,
            typer.Option(
                "--calibration",
                help="Rig calibration (rig.yaml or Kalibr camchain); default: the recording's.",
            ),
        ] = None,
        log_level: Annotated[
            str, typer.Option("--log-level", help="critical, error, warning, info, debug.")
        ] = "info",
    ) -> None:
        """Run the depth service (HTTP API + dashboard). With no config at all, or --demo, it serves
        a simulated rig so you see live depth at once."""
        from service.serve import run_serve  # FastAPI/uvicorn only when serving

        run_serve(
            config,
            demo=demo,
            host=host,
            port=port,
            recording=recording,
            calibration=calibration,
            log_level=log_level.lower(),
        )

    register_rig_commands(app)
    return app


def main() -> None:
    app = build_app()
    try:
        app()
    except (CalibrationError, RigError, ServiceError) as err:
        if os.environ.get("RIG_DEBUG"):
            raise
        err_console.print(f"[red]error:[/red] {' '.join(str(err).split())}", highlight=False, soft_wrap=True)
        sys.exit(2)
    except KeyboardInterrupt:
        sys.exit(130)
    except Exception as err:  # a bug: still one line, with the way to get the traceback
        if os.environ.get("RIG_DEBUG"):
            raise
        err_console.print(
            f"[red]internal error:[/red] {type(err).__name__}: {' '.join(str(err).split())} "
            "(run with RIG_DEBUG=1 for the traceback)",
            highlight=False,
            soft_wrap=True,
        )
        sys.exit(1)


if __name__ == "__main__":
    main()
