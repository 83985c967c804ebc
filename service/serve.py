"""Serving the app: a bound socket, then uvicorn until SIGINT/SIGTERM.

The socket is bound before any slow work (a busy port is a :class:`ServiceError`, reported as
one line, not a traceback after startup). Uvicorn handles SIGINT/SIGTERM: it stops accepting,
gives open streams ``GRACEFUL_S`` to finish, and the app's lifespan joins the worker and capture
threads. ``rig serve`` (:mod:`cli.serve`) puts settings, socket and runtime together.
"""

from __future__ import annotations

import contextlib
import resource
import signal
import socket
import threading
from collections.abc import Iterator
from typing import Any

import uvicorn

from service.app import create_app
from service.connections import ConnectionLimits, guarded_protocol
from service.errors import ServiceError
from service.runtime import Runtime
from service.settings import Settings

__all__ = [
    "FD_RESERVE",
    "GRACEFUL_S",
    "LOG_LEVELS",
    "bind_socket",
    "ensure_fd_room",
    "fds_needed",
    "run_server",
    "uvicorn_config",
]

GRACEFUL_S = 3
LOG_LEVELS = ("critical", "error", "warning", "info", "debug")
#: File descriptors kept free of HTTP connections: cameras, frame and recording files, the LUT
#: cache, sensors, the listening socket, Python's own.
FD_RESERVE = 128


def bind_socket(host: str, port: int) -> socket.socket:
    """A listening-ready TCP socket on ``host:port`` (port 0 = any free port); ServiceError
    naming the address when it cannot be had."""
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except socket.gaierror as err:
        raise ServiceError(f"cannot resolve host {host!r}: {err.strerror}") from err
    family, _, _, _, address = infos[0]
    # proto must be IPPROTO_TCP (not 0): asyncio sets TCP_NODELAY on accepted connections only
    # then, and without it Nagle + delayed ACK add ~40 ms to every keep-alive response.
    sock = socket.socket(family, socket.SOCK_STREAM, socket.IPPROTO_TCP)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind(address)
    except OSError as err:
        sock.close()
        raise ServiceError(f"cannot listen on {host}:{port}: {err.strerror}") from err
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


def fds_needed(settings: Settings) -> int:
    """Descriptors ``rig serve`` may hold: one per HTTP connection, three per Foxglove viewer (its
    connection, the gate's to the SDK and the SDK's end of it) and :data:`FD_RESERVE`."""
    fox = settings.server.foxglove
    return settings.server.max_connections + (3 * fox.max_viewers if fox.enabled else 0) + FD_RESERVE


def ensure_fd_room(settings: Settings) -> int:
    """Make sure ``server.max_connections`` connections (and Foxglove's viewers) leave
    :data:`FD_RESERVE` descriptors free (raising the soft ``RLIMIT_NOFILE`` up to the hard one if
    needed): the process's limit, or ServiceError naming the setting."""
    need = fds_needed(settings)
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft != resource.RLIM_INFINITY and soft < need:
        if hard != resource.RLIM_INFINITY and hard < need:
            raise ServiceError(
                f"settings: field 'server.max_connections': {settings.server.max_connections} connections "
                f"need {need} file descriptors, and this process may open {hard} (ulimit -n; "
                "LimitNOFILE= in a systemd unit): lower server.max_connections or raise the limit"
            )
        resource.setrlimit(resource.RLIMIT_NOFILE, (need, hard))
        soft = need
    return soft


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
