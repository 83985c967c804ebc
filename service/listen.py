"""The listening socket and the descriptors it needs, before anything slow is imported.

``rig serve`` binds its port first (standard library only here), so that a busy port is one line
at once, not after the depth pipeline, the app and uvicorn have been imported (seconds on a busy
two-core board). :mod:`service.serve` serves on the socket.
"""

from __future__ import annotations

import errno
import resource
import socket
from typing import TYPE_CHECKING

from service.errors import ServiceError

if TYPE_CHECKING:
    from service.settings import Settings

__all__ = ["FD_RESERVE", "LOG_LEVELS", "PortBusy", "bind_socket", "ensure_fd_room", "fds_needed"]

LOG_LEVELS = ("critical", "error", "warning", "info", "debug")
#: File descriptors kept free of HTTP connections: cameras, frame and recording files, the LUT
#: cache, sensors, the listening socket, Python's own.
FD_RESERVE = 128


class PortBusy(ServiceError):
    """Another process listens on the address (``rig serve`` adds the ``--port`` hint)."""


def bind_socket(host: str, port: int) -> socket.socket:
    """A listening-ready TCP socket on ``host:port`` (port 0 = any free port); ServiceError
    naming the address when it cannot be had (:class:`PortBusy` when it is in use)."""
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
        kind = PortBusy if err.errno == errno.EADDRINUSE else ServiceError
        raise kind(f"cannot listen on {host}:{port}: {err.strerror}") from err
    sock.set_inheritable(True)
    return sock


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
