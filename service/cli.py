"""The ``rig`` console command: ``serve`` plus the subcommands of ``rig.cli``.

Errors from the packages become one line on stderr and exit status 2; nothing reaches the user
as a traceback unless ``RIG_DEBUG=1``.
"""

from __future__ import annotations

import os
import sys

import typer

from calibration.errors import CalibrationError
from rig.cli import register as register_rig_commands
from rig.cli.common import STUB_SETTINGS, err_console, not_ready
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

    @app.command("serve", context_settings=STUB_SETTINGS, help="Not implemented yet (issue #6).")
    def serve(ctx: typer.Context) -> None:
        not_ready("serve", 6)

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
