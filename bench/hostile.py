"""Hostile clients against the real service, one attack class at a time.

Starts ``rig serve --demo`` (or the quick recording with ``--quick``) in a child process for each
attack and measures what a robot's supervisor would see while it runs: ``/health`` latency and
failures (a probe on a fresh connection every 0.1 s, 5 s timeout), the service's RSS and open
file descriptors (``/proc``), and per attack:

- ``patch``: ``--writers`` concurrent ``PATCH /config``, each of a different stereo field, then as
  many of one field: changes acknowledged (200) but not in effect afterwards (lost updates), and
  whether the last write of the one field (in the server's order, its ``ETag`` revision) won;
- ``headers``: one request with ``--header-mib`` MiB of header lines (and one with one header of
  that size): how long the server takes to answer it, with what, and ``/health`` meanwhile;
- ``streams``: ``--streams`` ``/stream.mjpg`` clients that read the status line and then stop
  reading, held ``--hold-s``: their statuses, RSS during and ``--after-s`` after they leave;
- ``slow``: one stream reader on a slow link (16 KiB receive buffer, ``--slow-kib-s`` KiB/s):
  the age of the parts it receives (``X-Timestamp-Ns`` against CLOCK_MONOTONIC when read);
- ``slowloris``: ``--sockets`` connections sending one header line every ``--drip-s``, with the
  service's descriptor limit lowered to 1024 (a systemd service's default soft limit): server
  descriptors, how many attack connections it closed, corrupt frames counted meanwhile;
- ``idle``: ``--idle`` connections that never send a byte: how many are open after ``--idle-s``;
- ``recording``: an active recording holding ``--files`` files: ``/health`` latency with four
  pollers (the files are empty extras in the recording's directory, standing for an hour of
  frames);
- ``poll``: 32 clients (16 on ``/depth``, 16 on ``/health``, 10 requests/s each) for
  ``--poll-s``: peak RSS against the service's memory budget (``rig_memory_budget_bytes`` in
  ``/metrics``, where it has one);
- ``listing``: ``GET /recordings`` (``--listings`` times) beside a recording a crash left with
  ``--files`` frame files and one with a malformed recording.json: status and latency;
- ``fox_stalled``, ``fox_idle``, ``fox_flood``, ``fox_reset``: the same against the Foxglove port
  (``server.foxglove`` turned on for these), :mod:`bench.hostile_foxglove`.

Run: ``.venv/bin/python -m bench.hostile`` (``--attack NAME`` for one, ``--quick`` for seconds).
The machine is shared: figures taken under other load are pessimistic.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import socket
import time
from collections.abc import Callable, Coroutine
from typing import Any

import httpx
from rich.table import Table

from bench.common import add_common_arguments, bench_cache_dir, console, finish, machine_info, print_machine
from bench.common import summary as stats_of
from bench.hostile_clients import (
    HealthProbe,
    closed_by_peer,
    flood_headers,
    flooded,
    hold_and_leave,
    open_sockets,
    read_stream_slowly,
)
from bench.hostile_foxglove import FOXGLOVE_ATTACKS, foxglove_env
from bench.hostile_recordings import AUTH, TOKEN, attack_listing, attack_recording
from bench.service_proc import ServiceProcess, free_port, quick_serve_args

__all__ = ["ATTACKS", "FIELD_CHANGES", "main"]


# Stereo fields and values a writer may set, each valid with any combination of the others.
FIELD_CHANGES: tuple[tuple[str, Any], ...] = (
    ("prefilter_cap", 40),
    ("texture_threshold", 12),
    ("speckle_size", 120),
    ("speckle_range", 3),
    ("disp12_max_diff", 2),
    ("uniqueness_ratio", 12.0),
    ("lr_max_diff", 1.5),
    ("median", 3),
    ("temporal_alpha", 0.2),
    ("temporal_reset", 0.8),
    ("confidence_sigma", 0.2),
    ("subpixel_window", 13),
    ("lr_check", True),
)


def _host_port(svc: ServiceProcess) -> tuple[str, int]:
    return "127.0.0.1", svc.port


# ----- attacks -------------------------------------------------------------------------------------
async def attack_patch(svc: ServiceProcess, args: argparse.Namespace) -> dict[str, Any]:
    url = svc.url
    async with httpx.AsyncClient(timeout=60.0, headers=AUTH) as c:
        current = (await c.get(url + "/config")).json()["stereo"]
        changes = [(f, v) for f, v in FIELD_CHANGES if current.get(f) != v][: args.writers]

        async def patch(stereo: dict[str, Any]) -> httpx.Response:
            return await c.patch(url + "/config", json={"stereo": stereo})

        replies = await asyncio.gather(*(patch({f: v}) for f, v in changes))
        acked = [(f, v) for (f, v), r in zip(changes, replies, strict=True) if r.status_code == 200]
        final = (await c.get(url + "/config")).json()["stereo"]
        lost = [f for f, v in acked if final[f] != v]
        values = [200 + k for k in range(args.writers)]
        same = await asyncio.gather(*(patch({"speckle_size": v}) for v in values))
        final_same = (await c.get(url + "/config")).json()["stereo"]["speckle_size"]
    ok_same = [(v, r) for v, r in zip(values, same, strict=True) if r.status_code == 200]
    revisions = [(int(r.headers["etag"].strip('"')), v) for v, r in ok_same if "etag" in r.headers]
    last = max(revisions)[1] if len(revisions) == len(ok_same) and revisions else None
    return {
        "different_fields": len(changes),
        "acknowledged": len(acked),
        "lost_updates": len(lost),
        "lost_fields": lost,
        "same_field_writers": len(values),
        "same_field_acknowledged": len(ok_same),
        "same_field_final": final_same,
        "same_field_last_in_server_order": last,
        "same_field_last_wins": None if last is None else last == final_same,
    }


async def attack_headers(svc: ServiceProcess, args: argparse.Namespace) -> dict[str, Any]:
    host, port = _host_port(svc)
    out: dict[str, Any] = {"mib": args.header_mib}
    for name, giant in (("lines", False), ("giant", True)):
        probe = HealthProbe(host, port).start()
        rss0 = svc.rss_mb()
        flood = await flood_headers(host, port, args.header_mib, giant=giant)
        await asyncio.sleep(1.0)
        health = await probe.stop()
        out[name] = {**flood, "health": health, "rss_growth_mb": svc.rss_mb() - rss0}
    return out


async def _open_streams(host: str, port: int, n: int) -> tuple[list[socket.socket], dict[int, int]]:
    """``n`` stream requests that read the status line and then stop reading."""
    socks: list[socket.socket] = []
    statuses: dict[int, int] = {}
    loop = asyncio.get_running_loop()

    async def one() -> None:
        s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        s.setblocking(False)
        try:
            await loop.sock_connect(s, (host, port))
            await loop.sock_sendall(s, f"GET /stream.mjpg HTTP/1.1\r\nHost: {host}\r\n\r\n".encode())
            async with asyncio.timeout(30.0):
                line = await loop.sock_recv(s, 12)
            status = int(line.split(b" ")[1]) if line.startswith(b"HTTP/1.1 ") else 0
        except (OSError, TimeoutError, ValueError, IndexError):
            status = 0
        statuses[status] = statuses.get(status, 0) + 1
        socks.append(s)

    for k in range(0, n, 50):
        await asyncio.gather(*(one() for _ in range(min(50, n - k))))
    return socks, statuses


async def attack_streams(svc: ServiceProcess, args: argparse.Namespace) -> dict[str, Any]:
    host, port = _host_port(svc)
    statuses: dict[int, int] = {}

    async def open_streams() -> list[socket.socket]:
        socks, counts = await _open_streams(host, port, args.streams)
        statuses.update(counts)
        return socks

    figures = await hold_and_leave(svc, open_streams, args.hold_s, args.after_s)
    return {
        "streams": args.streams,
        "statuses": {str(k): v for k, v in sorted(statuses.items())},
        **figures,
    }


async def attack_slow(svc: ServiceProcess, args: argparse.Namespace) -> dict[str, Any]:
    host, port = _host_port(svc)
    ages = await read_stream_slowly(host, port, args.slow_kib_s, args.slow_s)
    late = ages[len(ages) // 2 :]  # once the pipe is full
    s = stats_of(late)
    return {"kib_per_s": args.slow_kib_s, "parts": len(ages), "age_p50_s": s["p50"], "age_max_s": s["max"]}


async def attack_slowloris(svc: ServiceProcess, args: argparse.Namespace) -> dict[str, Any]:
    host, port = _host_port(svc)
    async with flooded(svc.pid, svc.url, host, port) as flood:
        head = f"GET /health HTTP/1.1\r\nHost: {host}\r\n".encode()
        flood.socks, refused = await open_sockets(host, port, args.sockets, head)
        flood.sample()
        until = time.monotonic() + args.slowloris_s
        k = 0
        while time.monotonic() < until:
            for s in flood.socks:
                with contextlib.suppress(OSError):
                    s.send(f"X-{k}: {k}\r\n".encode())
            k += 1
            flood.sample()
            await asyncio.sleep(args.drip_s)
    return {"sockets": args.sockets, "connect_failed": refused, **flood.figures}


async def attack_idle(svc: ServiceProcess, args: argparse.Namespace) -> dict[str, Any]:
    host, port = _host_port(svc)
    socks = []
    for _ in range(args.idle):
        s = socket.create_connection((host, port))
        socks.append(s)
    await asyncio.sleep(args.idle_s)
    closed = sum(closed_by_peer(s) for s in socks)
    for s in socks:
        s.close()
    return {"connections": args.idle, "after_s": args.idle_s, "closed_by_server": closed}


async def attack_poll(svc: ServiceProcess, args: argparse.Namespace) -> dict[str, Any]:
    until = time.monotonic() + args.poll_s
    errors = 0
    requests = 0

    # One client, one keep-alive connection per polling task (making 32 clients costs seconds of CPU).
    limits = httpx.Limits(max_connections=32, max_keepalive_connections=32)
    shared = httpx.AsyncClient(base_url=svc.url, timeout=10.0, limits=limits)

    async def client(path: str, k: int) -> None:
        nonlocal errors, requests
        await asyncio.sleep(k * 0.1 / 16)
        while time.monotonic() < until:
            t0 = time.monotonic()
            try:
                errors += (await shared.get(path)).status_code != 200
            except httpx.HTTPError:
                errors += 1
            requests += 1
            await asyncio.sleep(max(0.0, 0.1 - (time.monotonic() - t0)))

    rss0 = svc.rss_mb()
    async with shared:
        tasks = [asyncio.ensure_future(client(p, k)) for p in ("/depth", "/health") for k in range(16)]
        peak = rss0
        while not all(t.done() for t in tasks):
            await asyncio.sleep(0.5)
            peak = max(peak, svc.rss_mb())
        await asyncio.gather(*tasks)
    async with httpx.AsyncClient(timeout=10.0) as c:
        text = (await c.get(svc.url + "/metrics")).text
    budget = None
    for line in text.splitlines():
        if line.startswith("rig_memory_budget_bytes "):
            budget = float(line.split()[1]) / 2**20
    return {
        "clients": 32,
        "requests": requests,
        "errors": errors,
        "rss_before_mb": rss0,
        "rss_peak_mb": peak,
        "budget_mb": budget,
    }


Attack = Callable[[ServiceProcess, argparse.Namespace], Coroutine[Any, Any, dict[str, Any]]]
ATTACKS: dict[str, Attack] = {
    "patch": attack_patch,
    "headers": attack_headers,
    "streams": attack_streams,
    "slow": attack_slow,
    "slowloris": attack_slowloris,
    "idle": attack_idle,
    "recording": attack_recording,
    "poll": attack_poll,
    "listing": attack_listing,
    **FOXGLOVE_ATTACKS,
}


def _quick(args: argparse.Namespace) -> None:
    args.writers, args.header_mib, args.streams, args.hold_s, args.after_s = 8, 2.0, 20, 2.0, 1.0
    args.slow_s, args.sockets, args.slowloris_s, args.idle, args.idle_s = 4.0, 50, 2.0, 10, 2.0
    args.files, args.recording_s, args.poll_s, args.viewers = 300, 2.0, 3.0, 4


def _row(figures: dict[str, Any]) -> str:
    """The figures as ``name: value`` lines (floats to 3 significant digits)."""

    def show(value: Any) -> str:
        if isinstance(value, float):
            return f"{value:.3g}"
        if isinstance(value, dict):
            return "{" + ", ".join(f"{k}: {show(v)}" for k, v in value.items()) + "}"
        return json.dumps(value, default=str)

    return "\n".join(f"{k}: {show(v)}" for k, v in figures.items())


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(prog="python -m bench.hostile", description=__doc__.split("\n\n")[0])
    add_common_arguments(parser)
    parser.add_argument("--attack", action="append", choices=sorted(ATTACKS), help="one class (repeatable)")
    parser.add_argument("--serve-args", default=None, help="rig serve arguments instead of --demo")
    parser.add_argument("--writers", type=int, default=13)
    parser.add_argument("--header-mib", type=float, default=32.0)
    parser.add_argument("--streams", type=int, default=300)
    parser.add_argument("--hold-s", type=float, default=20.0)
    parser.add_argument("--after-s", type=float, default=10.0)
    parser.add_argument("--slow-kib-s", type=float, default=64.0)
    parser.add_argument("--slow-s", type=float, default=40.0)
    parser.add_argument("--sockets", type=int, default=1100)
    parser.add_argument("--drip-s", type=float, default=1.0)
    parser.add_argument("--slowloris-s", type=float, default=20.0)
    parser.add_argument("--idle", type=int, default=50)
    parser.add_argument("--idle-s", type=float, default=30.0)
    parser.add_argument("--files", type=int, default=3000)
    parser.add_argument("--listings", type=int, default=10, help="GET /recordings (listing)")
    parser.add_argument("--recording-s", type=float, default=8.0)
    parser.add_argument("--poll-s", type=float, default=20.0)
    parser.add_argument("--viewers", type=int, default=25, help="Foxglove viewers (fox_stalled, fox_reset)")
    args = parser.parse_args(argv)
    if args.quick:
        _quick(args)
    serve_args = (
        quick_serve_args() if args.quick else (args.serve_args.split() if args.serve_args else ["--demo"])
    )
    info = machine_info()
    print_machine(info, "Hostile clients against rig serve")
    env = {"RIG_CACHE_DIR": str(bench_cache_dir() / "lut"), "RIG_API_TOKEN": TOKEN}
    results: dict[str, Any] = {"serve_args": serve_args}
    table = Table(title="rig serve under hostile clients (one fresh service per attack)")
    table.add_column("attack")
    table.add_column("figures")
    for name in args.attack or list(ATTACKS):
        fox_port = free_port()
        fox_env = foxglove_env(fox_port) if name.startswith("fox_") else {}
        with ServiceProcess([*serve_args, "--log-level", "warning"], {**env, **fox_env}) as svc:
            svc.foxglove_port = fox_port  # type: ignore[attr-defined]
            svc.wait_ready(600.0)
            time.sleep(1.0)
            figures: dict[str, Any] = asyncio.run(ATTACKS[name](svc, args))
            figures["service_alive"] = svc.proc.poll() is None
        results[name] = figures
        table.add_row(name, _row(figures))
        console.print(f"{name} done", highlight=False)
    return finish("hostile", info, results, args.json, table)


if __name__ == "__main__":
    main()
