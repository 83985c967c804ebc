"""Hostile clients on raw sockets against a real server: oversized request heads, connections
that send nothing or dribble, more connections than the cap, stream clients that stop reading
and a stream reader on a slow link. The service answers them within its limits
(:mod:`service.connections`, ``/stream.mjpg``) and ``/health`` stays reachable throughout."""

from __future__ import annotations

import asyncio
import contextlib
import socket
import time

import httpx
import pytest

from bench.hostile_clients import flood_headers, parse_parts, read_stream_slowly, read_until_closed
from service.routes.stream import SEND_BUFFER_BYTES
from tests.helpers.service import LiveServer, StartServer
from tests.helpers.waiting import wait_for

pytestmark = [pytest.mark.timeout(300)]


def _health_ok(live: LiveServer) -> bool:
    return httpx.get(live.base_url + "/health", timeout=5).status_code == 200


def test_oversized_request_heads_are_refused_431(start_server: StartServer) -> None:
    live = start_server(max_header_bytes=8192, max_headers=50)
    for giant in (False, True):  # 2 MiB of header lines; one header of 2 MiB
        flood = asyncio.run(flood_headers("127.0.0.1", live.port, 2.0, giant=giant, timeout_s=30))
        assert flood["status"] == 431, flood
    # Too many header lines within the byte limit.
    head = b"GET /health HTTP/1.1\r\nHost: x\r\n" + b"".join(b"X-%d: y\r\n" % k for k in range(60)) + b"\r\n"
    with socket.create_connection(("127.0.0.1", live.port)) as sock:
        sock.sendall(head)
        answer = read_until_closed(sock, 5)
    assert answer.startswith(b"HTTP/1.1 431") and b"50 header lines" in answer, answer[:300]
    # A head just within the limits is served.
    ok = httpx.get(live.base_url + "/health", headers={f"X-{k}": "y" * 100 for k in range(40)}, timeout=10)
    assert ok.status_code == 200
    assert _health_ok(live)


def test_connections_that_send_nothing_or_dribble_are_closed(start_server: StartServer) -> None:
    live = start_server(request_timeout_s=1.0)
    idle = [socket.create_connection(("127.0.0.1", live.port)) for _ in range(5)]
    dribbling = [socket.create_connection(("127.0.0.1", live.port)) for _ in range(5)]
    for sock in dribbling:
        sock.sendall(b"GET /health HTTP/1.1\r\n")
    t0 = time.monotonic()
    while time.monotonic() - t0 < 2.0:  # one header line every 0.2 s, past the timeout
        for k, sock in enumerate(dribbling):
            with contextlib.suppress(OSError):
                sock.sendall(b"X-%d: y\r\n" % k)
        time.sleep(0.2)
    answers = [read_until_closed(sock, 5) for sock in idle + dribbling]
    for sock in idle + dribbling:
        sock.close()
    assert all(a.startswith(b"HTTP/1.1 408") for a in answers), [a[:40] for a in answers]
    assert _health_ok(live)


def test_the_connection_cap_keeps_health_reachable(start_server: StartServer) -> None:
    live = start_server(max_connections=16, max_streams=4, request_timeout_s=60.0)
    connections = live.server.server_state.connections
    socks = []
    for _ in range(60):  # slowloris: a head that never ends
        sock = socket.create_connection(("127.0.0.1", live.port))
        sock.sendall(b"GET /health HTTP/1.1\r\nX-a: b\r\n")
        socks.append(sock)
    try:
        for _ in range(5):
            assert _health_ok(live)
        wait_for(lambda: len(connections) <= 16, 5, "the server to hold at most 16 connections")
        closed = sum(read_until_closed(s, 0.5) == b"" for s in socks)
        assert closed >= 60 - 16
    finally:
        for sock in socks:
            sock.close()


def _stalled_stream(port: int) -> tuple[socket.socket, int]:
    """A /stream.mjpg request that reads the status line and nothing more (4 KiB receive buffer)."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.connect(("127.0.0.1", port))
    sock.sendall(b"GET /stream.mjpg HTTP/1.1\r\nHost: x\r\n\r\n")
    sock.settimeout(10)
    line = sock.recv(12)
    return sock, int(line.split(b" ")[1])


def test_streams_are_bounded_and_clients_that_stop_reading_are_dropped(start_server: StartServer) -> None:
    live = start_server(max_streams=3, stream_stall_s=1.0)
    opened = [_stalled_stream(live.port) for _ in range(5)]
    assert sorted(status for _, status in opened) == [200, 200, 200, 503, 503]
    busy = httpx.get(live.base_url + "/stream.mjpg", timeout=10)
    assert busy.status_code == 503 and "server.max_streams" in busy.json()["detail"]
    assert _health_ok(live)
    # Three streams that take nothing are dropped once a part has waited stream_stall_s ...
    runtime = live.runtime
    wait_for(lambda: runtime.streams_open == 0, 15, "the stalled streams to be dropped")
    for sock, _ in opened:
        sock.close()
    # ... and a new client gets the newest frame: the one published when it asked, or a later one.
    newest = runtime.store.latest
    assert newest is not None
    with httpx.stream("GET", live.base_url + "/stream.mjpg", timeout=10) as r:
        assert r.status_code == 200
        data = b""
        for chunk in r.iter_bytes():
            data += chunk
            parts, _ = parse_parts(data)
            if parts:
                break
    assert int(parts[0]["x-frame-seq"]) >= newest.seq


def test_a_slow_reader_gets_the_newest_frame_not_a_queue(start_server: StartServer) -> None:
    live = start_server()
    rcvbuf, kib_per_s = 8192, 16.0
    ages = asyncio.run(read_stream_slowly("127.0.0.1", live.port, kib_per_s, 12.0, rcvbuf=rcvbuf))
    part_bytes = len(httpx.get(live.base_url + "/depth/colorized", timeout=10).content) + 512
    # At most one part, the kernel's send and receive buffers (each doubled by the kernel) are
    # in flight: the age of a part is that much data at the reader's rate, and some jitter.
    in_flight = part_bytes + 2 * SEND_BUFFER_BYTES + 2 * rcvbuf
    bound_s = in_flight / (kib_per_s * 1024) + 1.0
    late = ages[len(ages) // 2 :]
    print(f"\nslow reader: {len(ages)} parts, ages of the later half {min(late):.2f}-{max(late):.2f} s")
    assert len(ages) >= 4 and max(late) < bound_s, (ages, bound_s)
