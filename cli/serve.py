"""``rig serve``: settings → bound socket → runtime → uvicorn.

Order matters for the user: settings are validated first (a non-loopback bind without a token
is refused before anything else happens), then the socket is bound (a busy port is one line at
once: only the settings are imported by then, not the pipeline, the app or uvicorn), then the
demo is rendered if needed (with a progress bar) and the runtime is built (calibration, LUTs,
cameras).

The demo (``--demo``, or no cameras configured) without a configured API token makes one
(:func:`secrets.token_urlsafe`) and prints the dashboard's URL with it, as notebook servers do:
the dashboard and Swagger UI can then change the settings and record. A configured token is
never replaced, nor printed.
"""

from __future__ import annotations

import logging
import os
import secrets
import shutil
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from cli.console import console, err_console, progress_bar, warn
from cli.errors import fail
from cli.source_options import LeftTopicOption, MaxSkewOption, RightTopicOption

if TYPE_CHECKING:
    import socket

    from service.settings import Settings

__all__ = ["ServiceConfigOption", "command_hint", "register", "serve_settings", "served_url"]

#: The service's config file (``rig serve``, ``rig check``).
ServiceConfigOption = Annotated[
    Path | None,
    typer.Option("--config", "-c", metavar="FILE", help="YAML config file.", show_default="$RIG_CONFIG"),
]


def _deep_merge(a: dict[str, Any], b: dict[str, Any]) -> dict[str, Any]:
    out = dict(a)
    for k, v in b.items():
        out[k] = _deep_merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def recording_overrides(
    recording: Path, calibration: Path | None, bag: Mapping[str, Any] | None = None
) -> dict[str, Any]:
    """File cameras replaying ``recording`` at its recorded pace, looping, live timestamps;
    ``bag``: a ROS bag's ``left_topic``, ``right_topic`` and ``max_skew_ms``."""
    from rig.capture.recorded import open_recording
    from rig.errors import RecordingError
    from service.demo import replay_overrides

    fields = {k: v for k, v in (bag or {}).items() if v is not None}
    try:
        rec = open_recording(recording, **fields)
    except RecordingError as err:
        fail(f"--recording: {err}")
    calib = calibration or rec.calibration_path
    if calib is None:
        fail(f"--recording {recording}: it has no calibration.yaml; give --calibration FILE")
    return replay_overrides(rec.root, calib, "recorded", fields, rec.cameras)


def demo_recording() -> Path:
    """The demo's loop recording, rendered with a progress bar the first time."""
    from service.demo import DemoSpec, cached_demo_recording, ensure_demo_recording

    spec = DemoSpec()
    cached = cached_demo_recording(spec)
    if cached is not None:
        return cached
    with progress_bar(transient=False, on_stdout=True) as bar:
        tasks = {
            "render": bar.add_task("rendering the demo room (once; cached)", total=1),
            "noise": bar.add_task("adding sensor noise", total=spec.frames),
        }

        def step(name: str, done: int, total: int) -> None:
            bar.update(tasks[name], completed=done, total=total)

        return ensure_demo_recording(spec, progress=step)


def serve_settings(
    config: Path | None,
    *,
    demo: bool = False,
    host: str | None = None,
    port: int | None = None,
    recording: Path | None = None,
    calibration: Path | None = None,
    bag: Mapping[str, Any] | None = None,
) -> Settings:
    """The settings ``rig serve`` runs with (renders the demo if it is used and not cached).
    ``--demo`` and ``--recording`` bring their own cameras (and the demo its calibration): the
    configuration's are still validated, and said to be ignored. The demo gets an API token
    when none is configured (see the module doc)."""
    from service.demo import demo_overrides
    from service.settings import load_settings

    if demo and recording is not None:
        fail("--demo and --recording exclude each other")
    overrides: dict[str, Any] = {"server": {}}
    if host is not None:
        overrides["server"]["host"] = host
    if port is not None:
        overrides["server"]["port"] = port
    if calibration is not None:
        overrides["calibration"] = {"path": str(calibration)}
    base = load_settings(config, overrides)  # validates the bind before any slow work
    if recording is not None:
        _say_ignored(base, "--recording", calibration_too=False)
        overrides = _deep_merge(overrides, recording_overrides(recording, calibration, bag))
        return load_settings(config, overrides, replace=("cameras",))
    if demo or base.cameras is None:
        if demo:
            _say_ignored(base, "--demo", calibration_too=calibration is None)
            if calibration is not None:
                warn("--calibration is ignored with --demo: the demo brings its rendered rig's calibration")
        else:
            console.print("no cameras configured: serving the built-in demo (simulated rig)")
        overrides = _deep_merge(overrides, demo_overrides(demo_recording()))
        if base.server.api_token is None:
            overrides["server"]["api_token"] = secrets.token_urlsafe(24)
        return load_settings(config, overrides, replace=("cameras", "calibration"))
    return base


_REPLACEMENTS = {
    "--demo": "the demo replays its own rendered rig",
    "--recording": "file cameras replay the recording",
}


def _say_ignored(base: Settings, flag: str, *, calibration_too: bool) -> None:
    """One warning naming the configured sections that ``flag`` replaces."""
    ignored = ["cameras"] if base.cameras is not None else []
    if calibration_too and base.calibration.path is not None:
        ignored.append("calibration")
    if ignored:
        verb = "is" if ignored == ["calibration"] else "are"
        warn(f"{flag}: the configured {' and '.join(ignored)} {verb} ignored ({_REPLACEMENTS[flag]})")


def served_url(settings: Settings, port: int, token: str | None = None) -> str:
    """The dashboard's URL on ``port``; with ``token``, carrying it (``?token=``) for the page to
    take."""
    host = settings.server.host
    host_part = f"[{host}]" if ":" in host else host
    url = f"http://{host_part}:{port}/"
    return url if token is None else f"{url}?token={token}"


def command_hint(argv0: str | None = None, path: str | None = None) -> str | None:
    """How to reach this ``rig`` command when its directory is not on ``PATH`` (``make demo``
    runs ``.venv/bin/rig``: the other commands need ``. .venv/bin/activate``), else None."""
    script = Path(sys.argv[0] if argv0 is None else argv0)
    if script.name != "rig" or not script.parent.name:
        return None
    found = shutil.which("rig", path=os.environ.get("PATH", "") if path is None else path)
    if found is not None and Path(found).resolve() == script.resolve():
        return None
    bindir = script.parent.resolve()
    try:
        shown = bindir.relative_to(Path.cwd())
    except ValueError:
        shown = bindir
    return f"the rig command is {shown / 'rig'}; `. {shown / 'activate'}` puts it on PATH"


def _bind(settings: Settings) -> socket.socket:
    """The service's listening socket, a busy port said with the way out."""
    from service.listen import PortBusy, bind_socket

    try:
        return bind_socket(settings.server.host, settings.server.port)
    except PortBusy as err:
        fail(f"{err} (another `rig serve`?): choose another port with --port P, or --port 0 for any free one")


def _banner(settings: Settings, port: int, generated_token: str | None) -> None:
    url = served_url(settings, port)
    if generated_token is None:
        lines = [f"depth service: {url}  (dashboard; API docs at {url}docs; Ctrl+C stops)"]
    else:
        lines = [
            f"depth service: {served_url(settings, port, generated_token)}  (dashboard, with the demo's "
            "API token: its controls can change the settings and record; Ctrl+C stops)",
            f"API docs: {url}docs (Authorize with the token {generated_token})",
        ]
    hint = command_hint()
    if hint is not None:
        lines.append(hint)
    for line in lines:
        console.print(line, highlight=False, soft_wrap=True)


def run_serve(
    config: Path | None = None,
    *,
    demo: bool = False,
    host: str | None = None,
    port: int | None = None,
    recording: Path | None = None,
    calibration: Path | None = None,
    bag: Mapping[str, Any] | None = None,
    log_level: str = "info",
) -> None:
    # The bind is validated (loopback or token) and taken with only the settings imported; the
    # pipeline, FastAPI and uvicorn (seconds of imports on a busy board) come after.
    from service.errors import ServiceError
    from service.listen import LOG_LEVELS, bind_socket, ensure_fd_room
    from service.settings import load_settings

    if log_level not in LOG_LEVELS:
        fail(f"--log-level must be one of {', '.join(LOG_LEVELS)}, got {log_level!r}")
    logging.basicConfig(level=log_level.upper(), format="%(levelname)s %(name)s: %(message)s")
    early: dict[str, Any] = {"server": {k: v for k, v in (("host", host), ("port", port)) if v is not None}}
    first = load_settings(config, early)
    ensure_fd_room(first)
    sock = _bind(first)
    bound_port = sock.getsockname()[1]
    try:
        settings = serve_settings(
            config, demo=demo, host=host, port=port, recording=recording, calibration=calibration, bag=bag
        )
        fox = settings.server.foxglove
        if fox.enabled and fox.port:  # a busy port is one line now, not a failed startup later
            try:
                bind_socket(fox.host, fox.port).close()
            except ServiceError as err:
                raise ServiceError(f"server.foxglove: {err}") from err
        from service.runtime import Runtime
        from service.serve import run_server

        runtime = Runtime.build(settings)
    except BaseException:
        sock.close()
        raise
    generated = settings.server.token if first.server.api_token is None else None
    _banner(settings, bound_port, generated)
    run_server(settings, runtime, sock, log_level)
    err_console.print("depth service stopped (worker and capture threads joined)", highlight=False)


def register(app: typer.Typer) -> None:
    @app.command("serve")
    def serve(
        config: ServiceConfigOption = None,
        demo: Annotated[
            bool, typer.Option("--demo", help="Serve the built-in simulated rig (rendered once, cached).")
        ] = False,
        host: Annotated[
            str | None,
            typer.Option(
                metavar="ADDRESS",
                help="Bind address; non-loopback needs RIG_API_TOKEN.",
                show_default="127.0.0.1",
            ),
        ] = None,
        port: Annotated[
            int | None, typer.Option(metavar="PORT", help="TCP port; 0 = any free port.", show_default="8000")
        ] = None,
        recording: Annotated[
            Path | None,
            typer.Option(
                "--recording",
                metavar="PATH",
                help="Serve a recording directory, or a ROS bag with --left-topic/--right-topic (looped).",
            ),
        ] = None,
        left_topic: LeftTopicOption = None,
        right_topic: RightTopicOption = None,
        max_skew_ms: MaxSkewOption = None,
        calibration: Annotated[
            Path | None,
            typer.Option(
                "--calibration",
                metavar="FILE",
                help="Rig calibration (rig.yaml or Kalibr camchain).",
                show_default="the recording's",
            ),
        ] = None,
        log_level: Annotated[
            str,
            typer.Option("--log-level", metavar="LEVEL", help="critical, error, warning, info or debug."),
        ] = "info",
    ) -> None:
        """Run the depth service (HTTP API + dashboard).

        With no config at all, or --demo, it serves a simulated rig so you see live depth at once.
        """
        run_serve(
            config,
            demo=demo,
            host=host,
            port=port,
            recording=recording,
            calibration=calibration,
            bag={"left_topic": left_topic, "right_topic": right_topic, "max_skew_ms": max_skew_ms},
            log_level=log_level.lower(),
        )
