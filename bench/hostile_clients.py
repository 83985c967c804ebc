"""Raw-socket clients of the hostile-client benchmark and tests: a ``/health`` prober on fresh
connections, a request-head flood, a slow ``/stream.mjpg`` reader, the multipart parser, each
small enough to run by the hundred in one event loop (:mod:`bench.hostile`,
tests/reliability/test_hostile_clients.py)."""

from __future__ import annotations

import asyncio
import contextlib
import socket
import time
from dataclasses import dataclass, field
from typing import Any

from bench.common import summary as stats_of

__all__ = ["BOUNDARY", "HealthProbe", "flood_headers", "parse_parts", "raw_get", "read_stream_slowly"]

BOUNDARY = b"--frame\r\n"
HEALTH_TIMEOUT_S = 5.0


async def raw_get(host: str, port: int, path: str, timeout_s: float = HEALTH_TIMEOUT_S) -> tuple[int, float]:
    """``GET path`` on a fresh connection: (status, seconds); status 0 when it failed or timed out."""
    t0 = time.monotonic()
    writer = None
    try:
        async with asyncio.timeout(timeout_s):
            reader, writer = await asyncio.open_connection(host, port)
            writer.write(f"GET {path} HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n\r\n".encode())
            await writer.drain()
            head = await reader.readuntil(b"\r\n\r\n")
            status = int(head.split(b" ", 2)[1])
            await reader.read()  # to the close: the whole answer
    except (OSError, TimeoutError, ValueError, IndexError, asyncio.IncompleteReadError):
        status = 0
    finally:
        if writer is not None:
            writer.close()
    return status, time.monotonic() - t0


@dataclass
class HealthProbe:
    """``GET /health`` on a fresh connection every ``period_s`` while running."""

    host: str
    port: int
    period_s: float = 0.1
    latencies_s: list[float] = field(default_factory=list)
    failures: int = 0
    _task: asyncio.Task[None] | None = None

    async def _run(self) -> None:
        while True:
            status, seconds = await raw_get(self.host, self.port, "/health")
            self.latencies_s.append(seconds)
            self.failures += status != 200
            await asyncio.sleep(max(0.0, self.period_s - seconds))

    def start(self) -> HealthProbe:
        self._task = asyncio.get_running_loop().create_task(self._run())
        return self

    async def stop(self) -> dict[str, Any]:
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
        s = stats_of([x * 1e3 for x in self.latencies_s])
        return {"probes": s["n"], "p50_ms": s["p50"], "max_ms": s["max"], "failures": self.failures}


async def flood_headers(
    host: str, port: int, mib: float, *, giant: bool = False, chunk: int = 64 * 1024, timeout_s: float = 120.0
) -> dict[str, Any]:
    """One ``GET /health`` whose head carries ``mib`` MiB of header lines (or one header of that
    size): the status the server answered (0 = none), when, and how much it took."""
    total = int(mib * 1024 * 1024)
    line = b"X-Flood: " + b"a" * 90 + b"\r\n"
    t0 = time.monotonic()
    status, sent = 0, 0
    writer = None
    try:
        reader, writer = await asyncio.open_connection(host, port)
        writer.write(f"GET /health HTTP/1.1\r\nHost: {host}\r\n".encode())
        if giant:
            writer.write(b"X-Giant: ")
        block = b"a" * chunk if giant else line * (chunk // len(line))
        read = asyncio.ensure_future(reader.readuntil(b"\r\n\r\n"))
        while sent < total and not read.done():
            writer.write(block)
            sent += len(block)
            await writer.drain()
        if not read.done():
            writer.write(b"\r\n\r\n" if giant else b"\r\n")
            await writer.drain()
        async with asyncio.timeout(max(1.0, timeout_s - (time.monotonic() - t0))):
            head = await read
        status = int(head.split(b" ", 2)[1])
    except (OSError, TimeoutError, ValueError, IndexError, asyncio.IncompleteReadError):
        pass
    finally:
        if writer is not None:
            writer.close()
    return {"status": status, "answered_after_s": time.monotonic() - t0, "sent_mib": sent / 2**20}


def parse_parts(data: bytes) -> tuple[list[dict[str, str]], bytes]:
    """Whole multipart parts' headers in ``data`` (and the unparsed rest)."""
    parts: list[dict[str, str]] = []
    while True:
        start = data.find(BOUNDARY)
        end_head = data.find(b"\r\n\r\n", start)
        if start < 0 or end_head < 0:
            return parts, data
        head = data[start + len(BOUNDARY) : end_head].decode("latin-1")
        headers = {}
        for line in head.split("\r\n"):
            name, _, value = line.partition(":")
            headers[name.strip().lower()] = value.strip()
        length = int(headers.get("content-length", "0"))
        if len(data) < end_head + 4 + length:
            return parts, data
        parts.append(headers)
        data = data[end_head + 4 + length :]


async def read_stream_slowly(
    host: str, port: int, kib_per_s: float, seconds: float, rcvbuf: int = 16 * 1024
) -> list[float]:
    """Read ``/stream.mjpg`` at ``kib_per_s`` through a ``rcvbuf``-byte receive buffer (a slow
    link) for ``seconds``: the age in seconds of each part when its head was read."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
    sock.setblocking(False)
    loop = asyncio.get_running_loop()
    ages: list[float] = []
    try:
        await loop.sock_connect(sock, (host, port))
        await loop.sock_sendall(sock, f"GET /stream.mjpg HTTP/1.1\r\nHost: {host}\r\n\r\n".encode())
        buf = b""
        step = 4096
        until = time.monotonic() + seconds
        while time.monotonic() < until:
            try:
                async with asyncio.timeout(max(0.1, until - time.monotonic())):
                    chunk = await loop.sock_recv(sock, step)
            except TimeoutError:
                break
            if not chunk:
                break
            buf += chunk
            parts, buf = parse_parts(buf)
            now = time.monotonic_ns()
            ages += [(now - int(p["x-timestamp-ns"])) / 1e9 for p in parts if "x-timestamp-ns" in p]
            await asyncio.sleep(len(chunk) / (kib_per_s * 1024))
    finally:
        sock.close()
    return ages
