"""Raw-socket clients of the hostile-client benchmark and tests: a ``/health`` prober on fresh
connections, a request-head flood, a slow ``/stream.mjpg`` reader, the multipart parser, each
small enough to run by the hundred in one event loop (:mod:`bench.hostile`,
tests/reliability/test_hostile_clients.py)."""

from __future__ import annotations

import asyncio
import contextlib
import os
import resource
import socket
import time
from collections.abc import AsyncIterator, Awaitable, Callable
from dataclasses import dataclass, field
from typing import Any

import httpx

from bench.common import summary as stats_of
from bench.service_proc import ServiceProcess

__all__ = [
    "BOUNDARY",
    "Flood",
    "HealthProbe",
    "closed_by_peer",
    "fd_count",
    "flood_headers",
    "flooded",
    "health_doc",
    "hold_and_leave",
    "malloc_in_use_mb",
    "open_sockets",
    "parse_parts",
    "raw_get",
    "read_stream_slowly",
    "read_until_closed",
]

BOUNDARY = b"--frame\r\n"
HEALTH_TIMEOUT_S = 5.0


def fd_count(pid: int) -> int:
    """Open file descriptors of ``pid`` (-1 when it cannot be read)."""
    try:
        return len(os.listdir(f"/proc/{pid}/fd"))
    except OSError:
        return -1


def closed_by_peer(sock: socket.socket) -> bool:
    """Whether the server has closed ``sock`` (reads and drops whatever it sent first)."""
    try:
        while sock.recv(1 << 20, socket.MSG_DONTWAIT):
            pass
        return True
    except BlockingIOError:
        return False
    except OSError:
        return True


def read_until_closed(sock: socket.socket, timeout_s: float) -> bytes:
    """Everything the server sends until it closes, prefixed ``(still open)`` if it does not
    within ``timeout_s`` of quiet (and ended with ``(reset)`` if it resets)."""
    sock.settimeout(timeout_s)
    data = b""
    try:
        while chunk := sock.recv(65536):
            data += chunk
    except TimeoutError:
        return b"(still open) " + data
    except ConnectionResetError:
        return data + b"(reset)"
    return data


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


async def health_doc(url: str) -> dict[str, Any]:
    """``/health``'s document, or what came instead (``status`` says so)."""
    try:
        async with httpx.AsyncClient(timeout=30.0) as c:
            r = await c.get(url + "/health")
        doc: dict[str, Any] = r.json()
        if "cameras" in doc:
            return doc
        return {"status": f"HTTP {r.status_code}", "reasons": [str(doc)[:300]], "cameras": {}}
    except (httpx.HTTPError, ValueError) as err:
        return {"status": "no answer", "reasons": [f"{type(err).__name__}: {err}"], "cameras": {}}


async def malloc_in_use_mb(url: str) -> float | None:
    """What malloc has handed out and not had back (RSS keeps freed memory for reuse)."""
    async with httpx.AsyncClient(timeout=30.0) as c:
        text = (await c.get(url + "/metrics")).text
    for line in text.splitlines():
        if line.startswith("rig_malloc_in_use_bytes "):
            return float(line.split()[1]) / 2**20
    return None


def _corrupt_frames(doc: dict[str, Any]) -> int:
    return sum(int(c.get("frames_corrupt") or 0) for c in doc["cameras"].values())


@dataclass
class Flood:
    """What a descriptor flood measured: the attacker adds its sockets to ``socks`` and keeps
    ``fds_peak`` (the server's descriptors) up to date; :func:`flooded` does the rest."""

    pid: int
    socks: list[socket.socket] = field(default_factory=list)
    fds_peak: int = 0
    figures: dict[str, Any] = field(default_factory=dict)

    def sample(self) -> None:
        self.fds_peak = max(self.fds_peak, fd_count(self.pid))


@contextlib.asynccontextmanager
async def flooded(pid: int, url: str, host: str, port: int, limit: int = 1024) -> AsyncIterator[Flood]:
    """A flood of connections against the service ``pid`` (HTTP at ``url``, ``host:port``) with its
    descriptor limit lowered to ``limit`` (a systemd service's default): ``/health`` probed
    meanwhile; on leaving, how many sockets the server closed, ``/health`` during and 2 s after
    the sockets closed, and the frames counted corrupt, in ``Flood.figures``."""
    soft, hard = resource.prlimit(pid, resource.RLIMIT_NOFILE)
    resource.prlimit(pid, resource.RLIMIT_NOFILE, (min(limit, hard), hard))
    flood = Flood(pid)
    try:
        before = await health_doc(url)
        probe = HealthProbe(host, port).start()
        yield flood
        closed = sum(closed_by_peer(s) for s in flood.socks)
        health = await probe.stop()
        during = await health_doc(url)
        for s in flood.socks:
            s.close()
        await asyncio.sleep(2.0)
        after = await health_doc(url)
    finally:
        resource.prlimit(pid, resource.RLIMIT_NOFILE, (soft, hard))
    flood.figures = {
        "server_fds_peak": flood.fds_peak,
        "closed_by_server": closed,
        "corrupt_frames_counted": _corrupt_frames(after) - _corrupt_frames(before),
        "status_during": during["status"],
        "reasons_during": during["reasons"][:3],
        "status_after_leave": after["status"],
        "health": health,
    }


async def open_sockets(host: str, port: int, n: int, first: bytes = b"") -> tuple[list[socket.socket], int]:
    """``n`` connections (100 at a time) that send ``first`` and then nothing: the open sockets
    and how many could not connect within 10 s."""
    loop = asyncio.get_running_loop()
    socks: list[socket.socket] = []
    failed = 0

    async def one() -> None:
        nonlocal failed
        s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        s.setblocking(False)
        try:
            async with asyncio.timeout(10.0):
                await loop.sock_connect(s, (host, port))
                if first:
                    await loop.sock_sendall(s, first)
            socks.append(s)
        except (OSError, TimeoutError):
            failed += 1
            s.close()

    for k in range(0, n, 100):
        await asyncio.gather(*(one() for _ in range(min(100, n - k))))
    return socks, failed


async def hold_and_leave(
    svc: ServiceProcess,
    open_clients: Callable[[], Awaitable[list[socket.socket]]],
    hold_s: float,
    after_s: float,
    ended: Callable[[socket.socket], bool] = closed_by_peer,
) -> dict[str, Any]:
    """Clients opened by ``open_clients`` held ``hold_s`` and closed: the service's RSS before,
    at its peak, while held and ``after_s`` after they left, what malloc had in use then, the
    server's peak descriptors, how many clients it had closed (``ended``), ``/health`` meanwhile."""
    rss0, in_use0 = svc.rss_mb(), await malloc_in_use_mb(svc.url)
    probe = HealthProbe("127.0.0.1", svc.port).start()
    socks = await open_clients()
    peak, fds_peak = svc.rss_mb(), fd_count(svc.pid)
    until = time.monotonic() + hold_s
    while time.monotonic() < until:
        await asyncio.sleep(0.5)
        peak, fds_peak = max(peak, svc.rss_mb()), max(fds_peak, fd_count(svc.pid))
    held, in_use_held = svc.rss_mb(), await malloc_in_use_mb(svc.url)
    closed = sum(ended(s) for s in socks)
    health = await probe.stop()
    for s in socks:
        s.close()
    await asyncio.sleep(after_s)
    return {
        "rss_before_mb": rss0,
        "rss_peak_mb": peak,
        "rss_held_mb": held,
        "rss_after_leave_mb": svc.rss_mb(),
        "malloc_in_use_mb": {
            "before": in_use0,
            "held": in_use_held,
            "after_leave": await malloc_in_use_mb(svc.url),
        },
        "server_fds_peak": fds_peak,
        "closed_by_server": closed,
        "health": health,
    }
