"""Hostile viewers of the Foxglove port against a real server: a viewer that subscribes to every
topic and stops reading is dropped (and what the SDK queued for it freed), connections that never
send their upgrade request are answered 408 and closed, connections beyond ``max_viewers``
displace the one waiting longest or are answered 503, viewers that reset leave no error in the
log, a viewer sending a giant message is closed, and beyond loopback a viewer needs the token
(:mod:`service.foxglove_gate`)."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import socket
import time
from collections.abc import Iterator

import foxglove
import pytest
import websockets.frames as ws_frames
from websockets.frames import Frame, Opcode

from bench.hostile_clients import read_until_closed
from bench.hostile_foxglove import Viewer, ended_by_peer
from service.foxglove import gate_limits
from service.foxglove_gate import FoxgloveGate, GateLimits, ViewerFrames, close_frame
from service.settings import FoxgloveSettings
from tests.helpers.service import LiveServer, StartServer
from tests.helpers.waiting import wait_for

pytestmark = [pytest.mark.timeout(300)]

FOX = {"enabled": True, "port": 0, "max_fps": 10.0}
TOKEN = "foxglove-gate-test-token-0123"


def _fox_port(live: LiveServer) -> int:
    return int(live.app.state.foxglove.port)


def test_a_viewer_that_stops_reading_is_dropped(start_server: StartServer) -> None:
    live = start_server(foxglove={**FOX, "stall_s": 1.0})
    fox = live.app.state.foxglove
    reading = Viewer("127.0.0.1", fox.port)
    stalled = Viewer("127.0.0.1", fox.port, rcvbuf=4096)

    async def run() -> tuple[int, float, int]:
        assert await reading.connect() == 101 and await stalled.connect() == 101
        topics = await stalled.subscribe_all()
        await reading.subscribe_all()
        t0 = time.monotonic()
        while not ended_by_peer(stalled.sock):  # never reads again
            assert time.monotonic() - t0 < 30, "the stalled viewer is still connected"
            await reading.read_for(0.2)
        # Counted while the other stalled, not after: a starved test process (three workers on two
        # cores) can read too slowly itself, and the SDK then closes it as it should.
        return topics, time.monotonic() - t0, reading.messages  # it subscribed after the other stalled

    try:
        topics, seconds, later = asyncio.run(run())
    finally:
        reading.close()
        stalled.close()
    print(f"stalled viewer ({topics} topics) dropped after {seconds:.1f} s; meanwhile {later} to the other")
    assert topics >= 10
    assert fox.stats().dropped == 1
    assert later > 0  # the reading viewer kept getting messages meanwhile
    wait_for(lambda: live.runtime.health().status == "ok", 10, "health ok")


def test_connections_that_never_send_their_request_are_closed(start_server: StartServer) -> None:
    live = start_server(foxglove={**FOX, "handshake_timeout_s": 1.0})
    port = _fox_port(live)
    silent = [socket.create_connection(("127.0.0.1", port)) for _ in range(3)]
    try:
        answers = [read_until_closed(s, 10.0) for s in silent]
    finally:
        for s in silent:
            s.close()
    for answer in answers:
        assert answer.startswith(b"HTTP/1.1 408") and b'"detail"' in answer, answer[:200]


def test_connections_beyond_max_viewers_displace_or_are_refused(start_server: StartServer) -> None:
    live = start_server(foxglove={**FOX, "max_viewers": 2})
    port = _fox_port(live)
    first, second, third = (Viewer("127.0.0.1", port) for _ in range(3))

    async def run() -> tuple[int, int, int, bool]:
        a = await first.connect()
        silent = socket.create_connection(("127.0.0.1", port))  # waits for its request
        b = await second.connect()  # displaces the silent one
        displaced = await asyncio.to_thread(read_until_closed, silent, 5.0)
        silent.close()
        c = await third.connect()  # two viewers: 503
        return a, b, c, not displaced.startswith(b"(still open)")

    try:
        a, b, c, displaced = asyncio.run(run())
    finally:
        for v in (first, second, third):
            v.close()
    assert (a, b, c) == (101, 101, 503)
    assert displaced
    assert live.app.state.foxglove.stats().refused >= 2


def test_viewers_that_reset_log_no_errors(
    start_server: StartServer, caplog: pytest.LogCaptureFixture
) -> None:
    live = start_server(foxglove=FOX)
    port = _fox_port(live)
    viewers = [Viewer("127.0.0.1", port) for _ in range(4)]

    async def run() -> list[int]:
        assert all(s == 101 for s in await asyncio.gather(*(v.connect() for v in viewers)))
        await asyncio.gather(*(v.subscribe_all() for v in viewers))
        return list(await asyncio.gather(*(v.read_for(1.0) for v in viewers)))

    with caplog.at_level(logging.WARNING):
        received = asyncio.run(run())
        for v in viewers:
            v.reset()
        time.sleep(3.0)  # the server's sends to them fail meanwhile
    errors = [r for r in caplog.records if r.levelno >= logging.WARNING and r.name.startswith("foxglove")]
    assert all(n > 0 for n in received), received
    assert errors == [], [r.getMessage() for r in errors[:5]]
    assert live.app.state.foxglove.stats().viewers == 0


def test_a_viewer_sending_a_giant_message_is_closed(start_server: StartServer) -> None:
    live = start_server(foxglove=FOX)
    viewer = Viewer("127.0.0.1", _fox_port(live))

    async def run() -> bool:
        assert await viewer.connect() == 101
        viewer.protocol.send_text(b"x" * (2 << 20))
        data = b"".join(viewer.protocol.data_to_send())
        loop = asyncio.get_running_loop()
        with contextlib.suppress(OSError):
            await loop.sock_sendall(viewer.sock, data)
        deadline = time.monotonic() + 10
        while not ended_by_peer(viewer.sock) and time.monotonic() < deadline:
            await asyncio.sleep(0.1)
        return ended_by_peer(viewer.sock)

    try:
        assert asyncio.run(run())
    finally:
        viewer.close()
    assert live.app.state.foxglove.stats().dropped == 1


# ----- the token, on a gate in front of a bare foxglove-sdk server ---------------------------------
@pytest.fixture
def gate_with_token() -> Iterator[FoxgloveGate]:
    ctx = foxglove.Context()
    sdk = foxglove.start_server(host="127.0.0.1", port=0, context=ctx)
    limits = GateLimits(
        max_viewers=4,
        max_header_bytes=16384,
        handshake_timeout_s=5,
        idle_timeout_s=60,
        stall_s=5,
        token=TOKEN,
    )
    gate = FoxgloveGate("127.0.0.1", 0, int(sdk.port), limits)
    gate.start()
    yield gate
    gate.stop()
    sdk.stop()


def test_beyond_loopback_viewers_need_the_token(gate_with_token: FoxgloveGate) -> None:
    port = gate_with_token.port

    async def status(query: str = "", header: str | None = None) -> int:
        viewer = Viewer("127.0.0.1", port, query=query, authorization=header)
        try:
            return await viewer.connect()
        finally:
            viewer.close()

    assert asyncio.run(status()) == 401
    assert asyncio.run(status("?token=wrong-token-0123456789")) == 401
    assert asyncio.run(status(f"?token={TOKEN}")) == 101
    assert asyncio.run(status(header=f"Bearer {TOKEN}")) == 101
    assert asyncio.run(status(header="Bearer not-the-token-0123456")) == 401
    # Which addresses ask for it: beyond loopback only (settings refuse such an address without one).
    assert gate_limits(FoxgloveSettings(host="0.0.0.0"), TOKEN).token == TOKEN
    assert gate_limits(FoxgloveSettings(host="127.0.0.1"), TOKEN).token is None


# ----- frame boundaries --------------------------------------------------------------------------
def test_viewer_frames_follow_websockets_own_framing() -> None:
    """The gate's frame tracking against websockets' serialisation of masked client frames:
    every length class (7-bit, 16-bit, 64-bit), fragments with a ping between them, fed in
    pieces of every size from 1 byte."""
    frames = [
        Frame(Opcode.TEXT, b'{"op":"subscribe"}'),
        Frame(Opcode.BINARY, b"b" * 300, fin=False),
        Frame(Opcode.PING, b"p"),
        Frame(Opcode.CONT, b"c" * 70000),
        Frame(Opcode.TEXT, b""),
    ]
    wire = [f.serialize(mask=True) for f in frames]
    stream = b"".join(wire)
    ends = {sum(len(w) for w in wire[: k + 1]) for k in range(len(wire))}
    for piece in (1, 2, 3, 7, 64, 4096, len(stream)):
        tracker = ViewerFrames()
        boundaries = set()
        for i in range(0, len(stream), piece):
            assert tracker.feed(stream[i : i + piece]) is None
            if tracker.at_boundary:
                boundaries.add(min(i + piece, len(stream)))
        assert boundaries <= ends and len(stream) in boundaries, piece
    # A message beyond the limit, also when fragmented.
    small = ViewerFrames(max_message=1000)
    assert small.feed(Frame(Opcode.TEXT, b"x" * 1001).serialize(mask=True)) is not None
    small = ViewerFrames(max_message=1000)
    parts = [Frame(Opcode.TEXT, b"x" * 600, fin=False), Frame(Opcode.CONT, b"x" * 600)]
    assert small.feed(parts[0].serialize(mask=True)) is None
    assert small.feed(parts[1].serialize(mask=True)) is not None
    # The gate's Close frame is one websockets parses as a client's Close 1001.
    parsed = ws_frames.Close.parse(_unmask(close_frame()))
    assert parsed.code == 1001


def _unmask(frame: bytes) -> bytes:
    mask, payload = frame[2:6], frame[6:]
    return bytes(b ^ mask[i % 4] for i, b in enumerate(payload))
