"""``rig serve``: settings → runtime → bound socket → uvicorn, with one-line failures.

Order matters for the user: settings are validated first (a non-loopback bind without a token
is refused before anything else happens), then the socket is bound (a busy port is one line, not
a traceback after startup), then the demo is rendered if needed and the runtime is built
(calibration, LUTs, cameras). Uvicorn handles SIGINT/SIGTERM: it stops accepting, gives open
streams ``GRACEFUL_S`` to finish, and the app's lifespan joins the worker and capture threads.
"""

from __future__ import annotations

import contextlib
import logging
import signal
import socket
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import uvicorn

from rig.cli.common import console, err_console, fail
from rig.errors import RecordingError
from rig.recording import Recording
from service.app import create_app
from service.demo import demo_overrides, ensure_demo_recording, replay_overrides
from service.runtime import Runtime
from service.settings import Settings, load_settings

__all__ = ["GRACEFUL_S", "LOG_LEVELS", "bind_socket", "run_serve", "serve_settings"]

log = logging.getLogger("service.serve")

GRACEFUL_S = 3
LOG_LEVELS = ("critical", "error", "warning", "info", "debug")


def _deep_merge(a: dict[str, Any], b: dict[str, Any]) -> dict[str, Any]:
    out = dict(a)
    for k, v in b.items():
        out[k] = _deep_merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def recording_overrides(recording: Path, calibration: Path | None) -> dict[str, Any]:
    """File cameras replaying ``recording`` at its recorded pace, looping, live timestamps."""
    try:
        rec = Recording(recording)
    except RecordingError as err:
        fail(f"--recording: {err}")
    calib = calibration or rec.calibration_path
    if calib is None:
        fail(f"--recording {recording}: it has no calibration.yaml; give --calibration FILE")
    return replay_overrides(rec.root, calib, "recorded")


def serve_settings(
    config: Path | None,
    *,
    demo: bool = False,
    host: str | None = None,
    port: int | None = None,
    recording: Path | None = None,
    calibration: Path | None = None,
) -> Settings:
    """The settings ``rig serve`` runs with (renders the demo if it is used and not cached)."""
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
        overrides = _deep_merge(overrides, recording_overrides(recording, calibration))
    elif demo or base.cameras is None:
        if not demo:
            console.print("no cameras configured: serving the built-in demo (simulated rig)")
        loop = ensure_demo_recording(console=console)
        overrides = _deep_merge(overrides, demo_overrides(loop))
    else:
        return base
    return load_settings(config, overrides)


def bind_socket(host: str, port: int) -> socket.socket:
    """A listening-ready TCP socket on ``host:port`` (port 0 = any free port); one-line failure."""
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except socket.gaierror as err:
        fail(f"cannot resolve --host {host!r}: {err.strerror}")
    family, _, _, _, address = infos[0]
    # proto must be IPPROTO_TCP (not 0): asyncio sets TCP_NODELAY on accepted connections only
    # then, and without it Nagle + delayed ACK add ~40 ms to every keep-alive response.
    sock = socket.socket(family, socket.SOCK_STREAM, socket.IPPROTO_TCP)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind(address)
    except OSError as err:
        sock.close()
        fail(f"cannot listen on {host}:{port}: {err.strerror}")
    sock.set_inheritable(True)
    return sock


class _Server(uvicorn.Server):
    """Uvicorn's server, except that a SIGINT/SIGTERM that led to a graceful shutdown is not
    re-raised afterwards: stopping the service is a normal end (exit status 0)."""

    @contextlib.contextmanager
    def capture_signals(self) -> Iterator[None]:
        if threading.current_thread() is not threading.main_thread():
            yield
            return
        original = {sig: signal.signal(sig, self.handle_exit) for sig in (signal.SIGINT, signal.SIGTERM)}
        try:
            yield
        finally:
            for sig, handler in original.items():
                signal.signal(sig, handler)


def run_serve(
    config: Path | None = None,
    *,
    demo: bool = False,
    host: str | None = None,
    port: int | None = None,
    recording: Path | None = None,
    calibration: Path | None = None,
    log_level: str = "info",
) -> None:
    if log_level not in LOG_LEVELS:
        fail(f"--log-level must be one of {', '.join(LOG_LEVELS)}, got {log_level!r}")
    logging.basicConfig(level=log_level.upper(), format="%(levelname)s %(name)s: %(message)s")
    # The bind is validated (loopback or token) and taken before any slow work (demo render, LUTs).
    early: dict[str, Any] = {"server": {k: v for k, v in (("host", host), ("port", port)) if v is not None}}
    first = load_settings(config, early)
    sock = bind_socket(first.server.host, first.server.port)
    bound_port = sock.getsockname()[1]
    try:
        settings = serve_settings(
            config, demo=demo, host=host, port=port, recording=recording, calibration=calibration
        )
        runtime = Runtime.build(settings)
    except BaseException:
        sock.close()
        raise
    server_cfg = settings.server
    app = create_app(settings, runtime=runtime)
    uv_config = uvicorn.Config(
        app,
        log_level=log_level,
        timeout_graceful_shutdown=GRACEFUL_S,
        access_log=log_level == "debug",
        proxy_headers=False,
        server_header=False,
    )
    host_part = f"[{server_cfg.host}]" if ":" in server_cfg.host else server_cfg.host
    url = f"http://{host_part}:{bound_port}/"
    console.print(
        f"depth service: {url}  (dashboard; API docs at {url}docs; Ctrl+C stops)",
        highlight=False,
        soft_wrap=True,
    )
    _Server(uv_config).run(sockets=[sock])
    err_console.print("depth service stopped (worker and capture threads joined)", highlight=False)
