"""Serving the app: a bound socket, then uvicorn until SIGINT/SIGTERM.

The socket is bound before any slow work, by :mod:`service.listen` (a busy port is a
:class:`ServiceError`, reported as one line, not a traceback after startup). Uvicorn handles
SIGINT/SIGTERM: it stops accepting, gives open streams ``GRACEFUL_S`` to finish, and the app's
lifespan joins the worker and capture threads. ``rig serve`` (:mod:`cli.serve`) puts settings,
socket and runtime together.
"""

from __future__ import annotations

import contextlib
import signal
import socket
import threading
from collections.abc import Iterator
from typing import Any

import uvicorn

from service.app import create_app
from service.connections import ConnectionLimits, guarded_protocol
from service.errors import ServiceError
from service.listen import FD_RESERVE, LOG_LEVELS, bind_socket, ensure_fd_room
from service.runtime import Runtime
from service.settings import Settings

__all__ = [
    "FD_RESERVE",
    "GRACEFUL_S",
    "LOG_LEVELS",
    "bind_socket",
    "ensure_fd_room",
    "run_server",
    "uvicorn_config",
]

GRACEFUL_S = 3


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


def uvicorn_config(app: Any, settings: Settings, log_level: str = "info", **kwargs: Any) -> uvicorn.Config:
    """Uvicorn's configuration for ``app``: the httptools parser with the connection limits of
    ``settings.server`` (:mod:`service.connections`), no WebSocket upgrades, no proxy headers."""
    server = settings.server
    limits = ConnectionLimits(
        max_connections=server.max_connections,
        max_header_bytes=server.max_header_bytes,
        max_headers=server.max_headers,
        request_timeout_s=server.request_timeout_s,
    )
    return uvicorn.Config(
        app,
        http=guarded_protocol(limits),
        ws="none",
        timeout_keep_alive=server.keep_alive_s,
        log_level=log_level,
        timeout_graceful_shutdown=GRACEFUL_S,
        access_log=log_level == "debug",
        proxy_headers=False,
        server_header=False,
        **kwargs,
    )


def run_server(settings: Settings, runtime: Runtime, sock: socket.socket, log_level: str = "info") -> None:
    """Serve ``create_app(settings, runtime=runtime)`` on ``sock`` until SIGINT/SIGTERM (the app
    starts the runtime and stops it at shutdown). ``log_level`` is one of :data:`LOG_LEVELS`."""
    if log_level not in LOG_LEVELS:
        raise ServiceError(f"log level must be one of {', '.join(LOG_LEVELS)}, got {log_level!r}")
    ensure_fd_room(settings)
    _Server(uvicorn_config(create_app(settings, runtime=runtime), settings, log_level)).run(sockets=[sock])
