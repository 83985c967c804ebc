"""Hostile clients of ``rig serve``'s Foxglove port (``server.foxglove``), for :mod:`bench.hostile`
and tests/reliability/test_foxglove_hostile.py.

Viewers speak foxglove.websocket.v1 through websockets' sans-I/O client protocol on raw
non-blocking sockets, so the attacker decides exactly when (and whether) it reads: a viewer can
subscribe to every topic and then never read again, its receive buffer kept small (a frozen
viewer on a slow link), or reset its connection (SO_LINGER 0) mid-stream.

- ``fox_stalled``: ``--viewers`` viewers subscribe to every topic and stop reading, held
  ``--hold-s``: RSS during and ``--after-s`` after they leave, the server's descriptors, how many
  the server closed, ``/health`` meanwhile;
- ``fox_idle``: ``--idle`` connections to the Foxglove port that never send a byte: how many the
  server closed after ``--idle-s``;
- ``fox_flood``: ``--sockets`` such connections with the service's descriptor limit at 1024:
  server descriptors, ``/health`` failures and statuses, corrupt frames counted meanwhile;
- ``fox_reset``: ``--viewers`` viewers subscribed to every topic that reset their connection
  after a second: the service's log lines at warning or above in the ``--after-s`` that follow.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import socket
import struct
import time
from pathlib import Path
from typing import Any

from websockets.client import ClientProtocol
from websockets.frames import Frame, Opcode
from websockets.http11 import Request, Response
from websockets.typing import Subprotocol
from websockets.uri import parse_uri

from bench.hostile_clients import closed_by_peer, flooded, health_doc, hold_and_leave, open_sockets

__all__ = ["FOXGLOVE_ATTACKS", "Viewer", "ended_by_peer", "foxglove_env"]

SUBPROTOCOLS = [Subprotocol("foxglove.sdk.v1"), Subprotocol("foxglove.websocket.v1")]


def _hex_address(address: tuple[str, int]) -> str:
    """An IPv4 address as /proc/net/tcp writes it (little-endian hex address, hex port)."""
    host, port = address
    return f"{socket.inet_aton(host)[::-1].hex().upper()}:{port:04X}"


def ended_by_peer(sock: socket.socket) -> bool:
    """Whether the server has let go of ``sock``'s connection, without reading from it: no
    socket of this machine (/proc/net/tcp) is connected to it any more. (A client that stopped
    reading may never see the server's reset: its window is closed.)"""
    try:
        mine = _hex_address(sock.getsockname())
    except OSError:
        return True
    for line in Path("/proc/net/tcp").read_text().splitlines()[1:]:
        fields = line.split()
        if fields[2] == mine and fields[3] == "01":  # remote = this socket, ESTABLISHED
            return False
    return True


def foxglove_env(port: int) -> dict[str, str]:
    """The environment turning ``rig serve``'s Foxglove server on at ``port``."""
    return {"RIG_SERVER__FOXGLOVE__ENABLED": "true", "RIG_SERVER__FOXGLOVE__PORT": str(port)}


class Viewer:
    """One foxglove.websocket.v1 viewer on a raw socket (see the module doc)."""

    def __init__(
        self,
        host: str,
        port: int,
        *,
        rcvbuf: int = 16 * 1024,
        query: str = "",
        authorization: str | None = None,
    ) -> None:
        self.host, self.port = host, port
        self.authorization = authorization
        self.protocol = ClientProtocol(parse_uri(f"ws://{host}:{port}/{query}"), subprotocols=SUBPROTOCOLS)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
        self.sock.setblocking(False)
        self.status = 0
        self.channels: dict[str, int] = {}
        self.messages = 0
        self.closed = False  # the server ended the connection

    async def _send_pending(self) -> None:
        data = b"".join(self.protocol.data_to_send())
        if data:
            await asyncio.get_running_loop().sock_sendall(self.sock, data)

    async def _pump(self, until: float) -> None:
        """Read and handle what arrives until ``until`` (monotonic) or the connection ends."""
        loop = asyncio.get_running_loop()
        while not self.closed and time.monotonic() < until:
            try:
                async with asyncio.timeout(max(0.01, until - time.monotonic())):
                    data = await loop.sock_recv(self.sock, 1 << 16)
            except TimeoutError:
                return
            except OSError:
                self.closed = True
                return
            if not data:
                self.closed = True
                self.protocol.receive_eof()
                return
            self.protocol.receive_data(data)
            for event in self.protocol.events_received():
                self._handle(event)
            await self._send_pending()
            await asyncio.sleep(0)  # data that is always ready must not starve the other viewers

    def _handle(self, event: Request | Response | Frame) -> None:
        if isinstance(event, Response):
            self.status = event.status_code
        elif isinstance(event, Frame) and event.opcode is Opcode.TEXT:
            doc = json.loads(bytes(event.data))
            if doc.get("op") == "advertise":
                self.channels.update({c["topic"]: int(c["id"]) for c in doc["channels"]})
        elif isinstance(event, Frame) and event.opcode is Opcode.BINARY:
            self.messages += 1

    async def connect(self, timeout_s: float = 10.0) -> int:
        """Connect and shake hands: the HTTP status of the answer (101 when upgraded, 0 for none)."""
        loop = asyncio.get_running_loop()
        try:
            async with asyncio.timeout(timeout_s):
                await loop.sock_connect(self.sock, (self.host, self.port))
            request = self.protocol.connect()
            if self.authorization is not None:
                request.headers["Authorization"] = self.authorization
            self.protocol.send_request(request)
            await self._send_pending()
            until = time.monotonic() + timeout_s
            while not self.status and not self.closed and time.monotonic() < until:
                await self._pump(min(until, time.monotonic() + 0.2))
        except (OSError, TimeoutError):
            pass
        return self.status

    async def subscribe_all(self, settle_s: float = 1.0) -> int:
        """Subscribe to every advertised topic (those advertised within ``settle_s``)."""
        await self._pump(time.monotonic() + settle_s)
        subs = [{"id": k + 1, "channelId": cid} for k, cid in enumerate(self.channels.values())]
        self.protocol.send_text(json.dumps({"op": "subscribe", "subscriptions": subs}).encode())
        with contextlib.suppress(OSError):
            await self._send_pending()
        return len(subs)

    async def read_for(self, seconds: float) -> int:
        """Read (and count) message data for ``seconds``."""
        with contextlib.suppress(OSError):
            await self._pump(time.monotonic() + seconds)
        return self.messages

    def reset(self) -> None:
        """Close with a TCP reset (SO_LINGER 0), as a crashed or unplugged client's kernel does."""
        with contextlib.suppress(OSError):
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        self.sock.close()

    def close(self) -> None:
        self.sock.close()


def _fox_port(svc: Any) -> int:
    return int(svc.foxglove_port)


async def _viewers(host: str, port: int, n: int) -> tuple[list[Viewer], dict[int, int], int]:
    viewers = [Viewer(host, port) for _ in range(n)]
    statuses = await asyncio.gather(*(v.connect() for v in viewers))
    subscribed = await asyncio.gather(*(v.subscribe_all() for v in viewers if v.status == 101))
    counts: dict[int, int] = {}
    for s in statuses:
        counts[s] = counts.get(s, 0) + 1
    return viewers, counts, max(subscribed, default=0)


async def attack_fox_stalled(svc: Any, args: argparse.Namespace) -> dict[str, Any]:
    port = _fox_port(svc)
    found: dict[str, Any] = {}

    async def open_viewers() -> list[socket.socket]:
        viewers, found["statuses"], found["topics"] = await _viewers("127.0.0.1", port, args.viewers)
        return [v.sock for v in viewers]

    figures = await hold_and_leave(svc, open_viewers, args.hold_s, args.after_s, ended=ended_by_peer)
    return {
        "viewers": args.viewers,
        "statuses": {str(k): v for k, v in sorted(found["statuses"].items())},
        "topics_subscribed": found["topics"],
        **figures,
    }


async def attack_fox_idle(svc: Any, args: argparse.Namespace) -> dict[str, Any]:
    host, port = "127.0.0.1", _fox_port(svc)
    socks, failed = await open_sockets(host, port, args.idle)
    await asyncio.sleep(args.idle_s)
    closed = sum(closed_by_peer(s) for s in socks)
    for s in socks:
        s.close()
    return {
        "connections": args.idle,
        "connect_failed": failed,
        "after_s": args.idle_s,
        "closed_by_server": closed,
    }


async def attack_fox_flood(svc: Any, args: argparse.Namespace) -> dict[str, Any]:
    host, port = "127.0.0.1", _fox_port(svc)
    statuses: dict[str, int] = {}
    async with flooded(svc.pid, svc.url, host, svc.port) as flood:
        flood.socks, failed = await open_sockets(host, port, args.sockets)
        flood.sample()
        until = time.monotonic() + args.slowloris_s
        while time.monotonic() < until:
            doc = await health_doc(svc.url)
            statuses[doc["status"]] = statuses.get(doc["status"], 0) + 1
            flood.sample()
            await asyncio.sleep(0.5)
    return {"sockets": args.sockets, "connect_failed": failed, "health_statuses": statuses, **flood.figures}


async def attack_fox_reset(svc: Any, args: argparse.Namespace) -> dict[str, Any]:
    host, port = "127.0.0.1", _fox_port(svc)
    viewers, statuses, topics = await _viewers(host, port, args.viewers)
    await asyncio.gather(*(v.read_for(1.0) for v in viewers))
    lines_before = len(svc.output)
    for v in viewers:
        v.reset()
    await asyncio.sleep(args.after_s)
    logged = [ln for ln in svc.output[lines_before:] if any(w in ln for w in ("ERROR", "WARNING", "Error"))]
    return {
        "viewers": args.viewers,
        "statuses": {str(k): v for k, v in sorted(statuses.items())},
        "topics_subscribed": topics,
        "log_lines_after_reset": len(logged),
        "first_lines": logged[:3],
    }


FOXGLOVE_ATTACKS = {
    "fox_stalled": attack_fox_stalled,
    "fox_idle": attack_fox_idle,
    "fox_flood": attack_fox_flood,
    "fox_reset": attack_fox_reset,
}
