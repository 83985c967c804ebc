"""The Foxglove port's gate: the limits of the HTTP port for the Foxglove WebSocket viewers.

foxglove-sdk's server (0.30) bounds none of what a hostile or careless viewer can cost: it takes
every connection, waits forever for a handshake that never comes, keeps a viewer that stops
reading (its per-viewer queue drops the oldest data message, but holds ``message_backlog`` of
them for as long as the viewer stays), checks no token, and logs an error for every message it
fails to send to a viewer that reset. Its Python API has no option for any of these. So the SDK
listens on an ephemeral loopback port, and the configured address is this gate: an asyncio server
on its own thread that reads each connection's HTTP upgrade request, checks it, then relays bytes
both ways over its own connection to the SDK. The gate bounds:

- connections (``max_viewers``): beyond, the connection that has waited longest for its request
  is closed to make room; if every one is a viewer, the new one is answered ``503``;
- the upgrade request: ``max_header_bytes`` (``431``) within ``handshake_timeout_s`` of the
  connection (``408``); where a token is required (bound beyond loopback), ``401`` without it;
- a viewer that stops reading: the relay reads from the SDK only as fast as the viewer takes it,
  so the SDK's queue (newest messages kept, ``message_backlog``) holds its backlog; one whose
  relay buffer has not drained for ``stall_s`` is closed, which frees that queue;
- a viewer that sends nothing and receives nothing for ``idle_timeout_s``: closed;
- what a viewer sends: a WebSocket message beyond :data:`MAX_VIEWER_MESSAGE` closes it (the
  server is read-only; a subscription is a few hundred bytes).

A viewer that leaves (closes, resets, or is dropped) is ended toward the SDK with a WebSocket
Close frame, so the SDK unregisters it at once instead of logging an error per queued message.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import json
import logging
import os
import socket
import struct
import threading
import time
from dataclasses import dataclass, field
from urllib.parse import parse_qs, urlsplit

from service.errors import SettingsError

__all__ = ["MAX_VIEWER_MESSAGE", "FoxgloveGate", "GateLimits", "GateStats", "ViewerFrames"]

log = logging.getLogger("service.foxglove")

MAX_VIEWER_MESSAGE = 1 << 20
_CHUNK = 1 << 18  # bytes relayed per read from the SDK
_WRITE_HIGH = 1 << 18  # relay buffer toward a viewer before the relay stops reading the SDK
_SDK_RCVBUF = 1 << 18  # the relay's receive buffer from the SDK (bounds what sits in sockets)
_CLOSE_WAIT_S = 2.0  # how long the SDK gets to end a connection after the viewer's Close
_SWEEP_S = 1.0
_REASONS = {401: "Unauthorized", 405: "Method Not Allowed", 408: "Request Timeout"}
_REASONS |= {431: "Request Header Fields Too Large", 503: "Service Unavailable"}


@dataclass(frozen=True)
class GateLimits:
    """What one viewer may cost (``server.foxglove`` and ``server.max_header_bytes``)."""

    max_viewers: int
    max_header_bytes: int
    handshake_timeout_s: float
    idle_timeout_s: float
    stall_s: float
    token: str | None  # required in the upgrade request when set


@dataclass(frozen=True)
class GateStats:
    """``viewers``: connections relayed now; ``refused``: requests answered 401/408/431/503 or
    displaced; ``dropped``: viewers closed for stalling or idling."""

    viewers: int
    refused: int
    dropped: int


class ViewerFrames:
    """Where the WebSocket frames a viewer sends begin and end (RFC 6455 §5.2 headers; payloads
    are skipped, not kept), and how large its current message is."""

    def __init__(self, max_message: int = MAX_VIEWER_MESSAGE) -> None:
        self.max_message = max_message
        self._header = bytearray()
        self._payload_left = 0
        self._message = 0

    @property
    def at_boundary(self) -> bool:
        return self._payload_left == 0 and not self._header

    def _header_size(self) -> int | None:
        if len(self._header) < 2:
            return None
        size = 2 + {126: 2, 127: 8}.get(self._header[1] & 0x7F, 0)
        return size + (4 if self._header[1] & 0x80 else 0)

    def _parse_header(self) -> str | None:
        h = self._header
        code = h[1] & 0x7F
        length = code if code < 126 else int.from_bytes(h[2 : 4 if code == 126 else 10], "big")
        self._header = bytearray()
        self._payload_left = length
        self._message += length
        if self._message > self.max_message:
            return f"a message of more than {self.max_message} bytes"
        if h[0] & 0x80 and not h[0] & 0x08:  # FIN of a data message (control frames interleave)
            self._message = 0
        elif h[0] & 0x08:
            self._message -= length
        return None

    def feed(self, data: bytes) -> str | None:
        """Follow ``data``; what is wrong with it (a message beyond the limit), or None."""
        i, n = 0, len(data)
        while i < n:
            if self._payload_left:
                take = min(self._payload_left, n - i)
                self._payload_left -= take
                i += take
                continue
            self._header.append(data[i])
            i += 1
            if len(self._header) == self._header_size():
                problem = self._parse_header()
                if problem:
                    return problem
        return None


def close_frame(code: int = 1001) -> bytes:
    """A client's (masked) WebSocket Close frame with ``code`` (1001: going away)."""
    payload = struct.pack("!H", code)
    mask = os.urandom(4)
    return bytes([0x88, 0x80 | len(payload)]) + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(payload))


def _answer(status: int, detail: str) -> bytes:
    body = json.dumps({"detail": detail}).encode()
    head = (
        f"HTTP/1.1 {status} {_REASONS[status]}\r\nContent-Type: application/json\r\n"
        f"Content-Length: {len(body)}\r\nConnection: close\r\n\r\n"
    )
    return head.encode() + body


def request_problem(head: bytes, token: str | None) -> tuple[int, str] | None:
    """What stops an upgrade request head (status, detail), or None to relay it."""
    lines = head.decode("latin-1").split("\r\n")
    parts = lines[0].split(" ")
    if len(parts) != 3 or parts[0] != "GET":
        return 405, "the Foxglove port takes only a WebSocket upgrade (GET)"
    if token is None:
        return None
    presented: list[str] = parse_qs(urlsplit(parts[1]).query).get("token", [])
    for line in lines[1:]:
        name, _, value = line.partition(":")
        scheme, _, credential = value.strip().partition(" ")
        if name.strip().lower() == "authorization" and scheme.lower() == "bearer":
            presented.append(credential.strip())
    if any(hmac.compare_digest(p.encode(), token.encode()) for p in presented):
        return None
    return 401, "the Foxglove port needs the API token: ?token=<token> or Authorization: Bearer <token>"


@dataclass(eq=False)
class _Connection:
    accepted: float
    writer: asyncio.StreamWriter
    task: asyncio.Task[None] | None = None
    viewer: bool = False  # past the upgrade request, relayed
    last_active: float = 0.0
    ended: str | None = None  # why the gate ended it
    frames: ViewerFrames = field(default_factory=ViewerFrames)

    def end(self, why: str) -> None:
        self.ended = self.ended or why
        if self.task is not None:
            self.task.cancel()


class FoxgloveGate:
    """The gate in front of the SDK's server at ``127.0.0.1:sdk_port`` (see the module doc):
    :meth:`start` listens on ``host:port`` (0: any free port, then :attr:`port`)."""

    def __init__(self, host: str, port: int, sdk_port: int, limits: GateLimits) -> None:
        self.host, self._want_port, self.sdk_port, self.limits = host, port, sdk_port, limits
        self.port = 0
        self._loop = asyncio.new_event_loop()
        self._thread: threading.Thread | None = None
        self._server: asyncio.Server | None = None
        self._conns: set[_Connection] = set()
        self._sweeper: asyncio.Task[None] | None = None
        self._viewers = self._refused = self._dropped = 0

    # ----- lifecycle (any thread) --------------------------------------------------------------
    def start(self) -> None:
        self._thread = threading.Thread(target=self._loop.run_forever, name="rig-foxglove-gate", daemon=True)
        self._thread.start()
        try:
            asyncio.run_coroutine_threadsafe(self._listen(), self._loop).result(30.0)
        except OSError as err:
            self.stop()
            raise SettingsError(
                f"server.foxglove: cannot listen on {self.host}:{self._want_port} ({err.strerror or err})"
            ) from err

    def stop(self) -> None:
        if self._thread is None:
            return
        with contextlib.suppress(Exception):
            asyncio.run_coroutine_threadsafe(self._close_all(), self._loop).result(10.0)
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(5.0)
        self._thread = None
        if not self._loop.is_running():
            self._loop.close()

    def stats(self) -> GateStats:
        """The counts (ints the gate's loop updates: read from any thread without a lock)."""
        return GateStats(self._viewers, self._refused, self._dropped)

    # ----- on the gate's loop ------------------------------------------------------------------
    async def _listen(self) -> None:
        self._server = await asyncio.start_server(
            self._serve, self.host, self._want_port, limit=self.limits.max_header_bytes, reuse_address=True
        )
        self.port = int(self._server.sockets[0].getsockname()[1])
        self._sweeper = self._loop.create_task(self._sweep())

    async def _close_all(self) -> None:
        if self._server is not None:
            self._server.close()
        if self._sweeper is not None:
            self._sweeper.cancel()
        tasks = [c.task for c in self._conns if c.task is not None]
        for c in list(self._conns):
            c.end("server stopped")
        await asyncio.gather(*tasks, return_exceptions=True)

    async def _sweep(self) -> None:
        """Ends viewers idle for ``idle_timeout_s``."""
        while True:
            await asyncio.sleep(_SWEEP_S)
            now = time.monotonic()
            for c in list(self._conns):
                if c.viewer and now - c.last_active > self.limits.idle_timeout_s:
                    c.end(f"idle for {self.limits.idle_timeout_s:g} s (server.foxglove.idle_timeout_s)")

    def _admit(self, conn: _Connection) -> bool:
        """Room for ``conn``: displaces the connection waiting longest for its request if needed;
        False when every connection is a viewer."""
        if len(self._conns) >= self.limits.max_viewers:
            waiting = [c for c in self._conns if not c.viewer]
            if not waiting:
                return False
            oldest = min(waiting, key=lambda c: c.accepted)
            self._conns.discard(oldest)
            self._refused += 1
            oldest.end("displaced")
        self._conns.add(conn)
        return True

    async def _refuse(
        self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter, status: int, detail: str
    ) -> None:
        """Answer ``status`` and close; what the client still sends is read and dropped for up to
        a second first, so that it gets the answer rather than a reset."""
        self._refused += 1
        with contextlib.suppress(OSError, RuntimeError, TimeoutError, asyncio.LimitOverrunError):
            writer.write(_answer(status, detail))
            writer.write_eof()
            async with asyncio.timeout(1.0):
                await writer.drain()
                while await reader.read(1 << 16):
                    pass
        writer.transport.abort()

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        now = time.monotonic()
        conn = _Connection(now, writer, asyncio.current_task(), last_active=now)
        if not self._admit(conn):
            n = self.limits.max_viewers
            await self._refuse(
                reader, writer, 503, f"{n} viewers are connected already (server.foxglove.max_viewers)"
            )
            return
        try:
            await self._handle(conn, reader, writer)
        except (asyncio.CancelledError, OSError, asyncio.IncompleteReadError):
            pass
        finally:
            self._conns.discard(conn)
            writer.transport.abort()

    async def _request(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> bytes | None:
        lim = self.limits
        try:
            async with asyncio.timeout(max(0.0, lim.handshake_timeout_s)):
                head = await reader.readuntil(b"\r\n\r\n")
        except TimeoutError:
            await self._refuse(reader, writer, 408, f"no request within {lim.handshake_timeout_s:g} s")
            return None
        except asyncio.LimitOverrunError:
            await self._refuse(reader, writer, 431, f"request head beyond {lim.max_header_bytes} bytes")
            return None
        problem = request_problem(head, lim.token)
        if problem is not None:
            await self._refuse(reader, writer, *problem)
            return None
        return head

    async def _handle(
        self, conn: _Connection, reader: asyncio.StreamReader, writer: asyncio.StreamWriter
    ) -> None:
        head = await self._request(reader, writer)
        if head is None:
            return
        up = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        up.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, _SDK_RCVBUF)
        up.setblocking(False)
        try:
            await self._loop.sock_connect(up, ("127.0.0.1", self.sdk_port))
        except OSError:
            up.close()
            raise
        up_reader, up_writer = await asyncio.open_connection(sock=up, limit=_CHUNK)
        writer.transport.set_write_buffer_limits(high=_WRITE_HIGH)
        conn.viewer, conn.last_active = True, time.monotonic()
        peer = writer.get_extra_info("peername")
        log.info("Foxglove viewer %s connected", peer)
        self._viewers += 1
        try:
            up_writer.write(head)
            why = await self._relay(conn, reader, writer, up_reader, up_writer)
        except asyncio.CancelledError:
            why = conn.ended or "server stopped"
            task = asyncio.current_task()
            if task is not None:
                task.uncancel()  # ended by the gate: still end the SDK's side below
        finally:
            self._viewers -= 1
        if conn.ended is not None and conn.ended != "server stopped":
            self._dropped += 1
            log.warning("Foxglove viewer %s dropped: %s", peer, why)
        else:
            log.info("Foxglove viewer %s left (%s)", peer, why)
        await self._end_upstream(conn, up_reader, up_writer)

    async def _relay(
        self,
        conn: _Connection,
        reader: asyncio.StreamReader,
        writer: asyncio.StreamWriter,
        up_reader: asyncio.StreamReader,
        up_writer: asyncio.StreamWriter,
    ) -> str:
        down = asyncio.ensure_future(self._to_viewer(conn, up_reader, writer))
        upward = asyncio.ensure_future(self._to_sdk(conn, reader, up_writer))
        try:
            done, _ = await asyncio.wait((down, upward), return_when=asyncio.FIRST_COMPLETED)
        finally:
            down.cancel()
            upward.cancel()
        first = done.pop()
        try:
            return str(first.result())
        except OSError as err:
            return f"connection error: {err.strerror or err}"

    async def _to_viewer(
        self, conn: _Connection, up_reader: asyncio.StreamReader, writer: asyncio.StreamWriter
    ) -> str:
        while True:
            data = await up_reader.read(_CHUNK)
            if not data:
                return "the server closed"
            conn.last_active = time.monotonic()
            writer.write(data)
            try:
                async with asyncio.timeout(self.limits.stall_s):
                    await writer.drain()
            except TimeoutError:
                conn.ended = f"stopped reading for {self.limits.stall_s:g} s (server.foxglove.stall_s)"
                return conn.ended

    async def _to_sdk(
        self, conn: _Connection, reader: asyncio.StreamReader, up_writer: asyncio.StreamWriter
    ) -> str:
        while True:
            data = await reader.read(1 << 16)
            if not data:
                return "closed"
            conn.last_active = time.monotonic()
            problem = conn.frames.feed(data)
            if problem:
                conn.ended = f"sent {problem}"
                return conn.ended
            up_writer.write(data)
            await up_writer.drain()

    async def _end_upstream(
        self, conn: _Connection, up_reader: asyncio.StreamReader, up_writer: asyncio.StreamWriter
    ) -> None:
        """Tell the SDK the viewer has gone (a Close frame where the viewer's bytes end on a frame
        boundary) and wait for it to close, dropping what it still sends."""
        with contextlib.suppress(OSError, RuntimeError, TimeoutError):
            if conn.frames.at_boundary:
                up_writer.write(close_frame())
            up_writer.write_eof()
            async with asyncio.timeout(_CLOSE_WAIT_S):
                while await up_reader.read(_CHUNK):
                    pass
        up_writer.transport.abort()
