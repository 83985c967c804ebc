"""Per-client limits of the HTTP server: uvicorn's httptools protocol with bounded request heads,
a request timeout and a connection cap, for a service that faces clients with no proxy in front.

Uvicorn bounds neither the head of a request on its httptools parser (``h11_max_incomplete_event_size``
applies to h11 only; httptools joins a header that arrives in pieces by copying, so a head of tens
of MiB costs seconds of event-loop time), nor the time a client takes to send it (its keep-alive
timeout runs only between requests: a connection that never sends a byte, or one header line a
second, is held forever), nor the number of connections (``limit_concurrency`` answers 503 only
once a request head is complete, so half-open connections still use up file descriptors).
:func:`guarded_protocol` adds, per :class:`ConnectionLimits`:

- **head size**: more than ``max_header_bytes`` received before the head is complete, or more
  than ``max_headers`` header lines, is answered 431 and the connection closed, before the
  parser has joined more than that;
- **request timeout**: a request's head and body must arrive within ``request_timeout_s`` of its
  first byte (of the connection, for the first request): 408 and close otherwise. Between requests
  uvicorn's keep-alive timeout applies;
- **connection cap**: beyond ``max_connections`` open connections, the one that has waited
  longest for a request (idle keep-alive, or a head still arriving) is closed to make room; if
  every connection is busy with a request, the new one is answered 503 and closed. So connections
  that send nothing cannot lock out a supervisor polling ``/health``: its fresh connection
  displaces them.

Responses that stream for long (``/stream.mjpg``) get the connection's :class:`TransportControl`
from ``scope["extensions"]``: to keep what is buffered for a slow reader to about one part and
to wait until the client has taken it.
"""

from __future__ import annotations

import asyncio
import functools
import json
import logging
import socket
from dataclasses import dataclass
from typing import Any, ClassVar

from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol

__all__ = ["EXTENSION", "ConnectionLimits", "TransportControl", "guarded_protocol", "transport_control"]

log = logging.getLogger("service.connections")

#: ``scope["extensions"]`` key of a request's :class:`TransportControl`.
EXTENSION = "rig.transport"


@dataclass(frozen=True)
class ConnectionLimits:
    max_connections: int
    max_header_bytes: int
    max_headers: int
    request_timeout_s: float


class TransportControl:
    """What a long response may do to its connection: buffer little, wait for the client to take
    what was sent, drop a client that takes nothing."""

    def __init__(self, protocol: HttpToolsProtocol) -> None:
        self._protocol = protocol

    def limit_buffering(self, kernel_bytes: int) -> None:
        """Pause the response's writes whenever anything is left unsent in user space (instead of
        at uvicorn's 64 KiB) and ask the kernel for a send buffer of ``kernel_bytes``."""
        transport = self._protocol.transport
        transport.set_write_buffer_limits(high=0, low=0)
        sock = transport.get_extra_info("socket")
        if sock is not None:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, kernel_bytes)

    async def writable(self, timeout_s: float) -> bool:
        """Wait until everything written so far has gone to the kernel; False if the client has
        not taken it within ``timeout_s``."""
        try:
            async with asyncio.timeout(timeout_s):
                await self._protocol.flow.drain()
        except TimeoutError:
            return False
        return True

    def abort(self) -> None:
        """Close the connection at once, dropping whatever is unsent."""
        self._protocol.transport.abort()


def transport_control(scope: Any) -> TransportControl | None:
    """The request's :class:`TransportControl`; None under another server (tests, proxies)."""
    control = scope.get("extensions", {}).get(EXTENSION)
    return control if isinstance(control, TransportControl) else None


def _raw_response(status: int, reason: str, detail: str) -> bytes:
    body = json.dumps({"detail": detail}).encode()
    return (
        f"HTTP/1.1 {status} {reason}\r\ncontent-type: application/json\r\n"
        f"content-length: {len(body)}\r\nconnection: close\r\n\r\n"
    ).encode() + body


class _GuardedProtocol(HttpToolsProtocol):
    """HttpToolsProtocol with :class:`ConnectionLimits` (see module doc)."""

    limits: ClassVar[ConnectionLimits]
    lingering: ClassVar[set[_GuardedProtocol]]  # refused, reading what the client still sends

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._awaiting_request = True  # no complete head yet for the next request
        self._waiting_since = self.loop.time()
        self._head_bytes = 0
        self._header_count = 0
        self._request_timer: asyncio.TimerHandle | None = None
        self._refused = False  # answered with a refusal: the rest of what the client sends is dropped

    # ----- connection ----------------------------------------------------------------------------
    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        if len(self.connections) > self.limits.max_connections and not self._make_room():
            busy = f"too many connections ({self.limits.max_connections})"
            self._refuse(503, "Service Unavailable", busy, linger=False)
            return
        self._arm_request_timer()

    def connection_lost(self, exc: Exception | None) -> None:
        self._cancel_request_timer()
        super().connection_lost(exc)

    def _make_room(self) -> bool:
        """Close the connection that has waited longest for a request; False if all are busy."""
        waiting = [
            c
            for c in self.connections
            if c is not self and isinstance(c, _GuardedProtocol) and c._awaiting_request
        ]
        if not waiting:
            return False
        oldest = min(waiting, key=lambda c: c._waiting_since)
        oldest._cancel_request_timer()
        oldest.transport.close()
        oldest.connections.discard(oldest)  # at once: connection_lost comes a loop turn later
        return True

    def _refuse(self, status: int, reason: str, detail: str, *, linger: bool = True) -> None:
        """Answer ``status`` and close. With ``linger``, what the client still sends is read and
        dropped for :data:`_LINGER_S` first (closing with unread data would reset the
        connection, and the client lose the answer), while fewer than ``max_connections``
        connections linger."""
        self._cancel_request_timer()
        self._unset_keepalive_if_required()
        self.connections.discard(self)
        self._refused = True
        transport = self.transport
        if transport.is_closing():
            return
        transport.write(_raw_response(status, reason, detail))
        if not linger or len(self.lingering) >= self.limits.max_connections or not transport.can_write_eof():
            transport.close()
            return
        transport.write_eof()
        self.lingering.add(self)

        def close() -> None:
            self.lingering.discard(self)
            transport.close()

        self.loop.call_later(_LINGER_S, close)

    # ----- request timeout -----------------------------------------------------------------------
    def _arm_request_timer(self) -> None:
        if self._request_timer is None:
            self._request_timer = self.loop.call_later(self.limits.request_timeout_s, self._request_timed_out)

    def _cancel_request_timer(self) -> None:
        if self._request_timer is not None:
            self._request_timer.cancel()
            self._request_timer = None

    def _request_timed_out(self) -> None:
        self._request_timer = None
        if self.transport.is_closing():
            return
        if self._awaiting_request:
            self._refuse(
                408, "Request Timeout", f"request not received within {self.limits.request_timeout_s:g} s"
            )
        else:  # the body is late: the route reading it sees the client gone
            self.transport.close()

    # ----- request head --------------------------------------------------------------------------
    def data_received(self, data: bytes) -> None:
        if self._refused:
            return
        if not self._awaiting_request:
            super().data_received(data)
            return
        self._arm_request_timer()
        room = self.limits.max_header_bytes + _HEAD_SLACK - self._head_bytes
        head, rest = data[:room], data[room:]
        self._head_bytes += len(head)
        super().data_received(head)
        if self.transport.is_closing():
            return
        if self._awaiting_request and self._head_bytes >= self.limits.max_header_bytes + _HEAD_SLACK:
            self._refuse_large_head()
        elif rest:  # a body or the next request after a complete head
            self.data_received(rest)

    def on_header(self, name: bytes, value: bytes) -> None:
        self._header_count += 1
        super().on_header(name, value)

    def on_headers_complete(self) -> None:
        self._awaiting_request = False
        extensions: dict[Any, Any] = self.scope.setdefault("extensions", {})
        extensions[EXTENSION] = TransportControl(self)
        size = len(self.url) + sum(len(n) + len(v) + 4 for n, v in self.headers)
        if self._header_count > self.limits.max_headers or size > self.limits.max_header_bytes:
            self.app = functools.partial(_head_too_large, self.limits)
        super().on_headers_complete()

    def on_message_complete(self) -> None:
        self._cancel_request_timer()
        super().on_message_complete()

    def on_response_complete(self) -> None:
        super().on_response_complete()
        # Unless a pipelined request (its head already parsed) has just been started.
        if not self.transport.is_closing() and (self.cycle is None or self.cycle.response_complete):
            self._awaiting_request = True
            self._waiting_since = self.loop.time()
            self._head_bytes = self._header_count = 0

    def _refuse_large_head(self) -> None:
        log.debug("refused a request head over %d bytes", self.limits.max_header_bytes)
        self._refuse(431, "Request Header Fields Too Large", _head_detail(self.limits))


_LINGER_S = 1.0
# The request line and the blank line are not headers; data of the next pipelined request or of
# a body can share the last chunk of a head.
_HEAD_SLACK = 8 * 1024


def _head_detail(limits: ConnectionLimits) -> str:
    return (
        f"request head larger than {limits.max_header_bytes} bytes or with more than "
        f"{limits.max_headers} header lines"
    )


async def _head_too_large(limits: ConnectionLimits, scope: Any, receive: Any, send: Any) -> None:
    body = json.dumps({"detail": _head_detail(limits)}).encode()
    headers = [
        (b"content-type", b"application/json"),
        (b"content-length", str(len(body)).encode()),
        (b"connection", b"close"),
    ]
    await send({"type": "http.response.start", "status": 431, "headers": headers})
    await send({"type": "http.response.body", "body": body})


def guarded_protocol(limits: ConnectionLimits) -> type[asyncio.Protocol]:
    """Uvicorn's httptools protocol class with ``limits`` (give it as ``uvicorn.Config(http=...)``)."""
    return type("GuardedHttpToolsProtocol", (_GuardedProtocol,), {"limits": limits, "lingering": set()})
