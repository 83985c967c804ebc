"""The HTTP API under load while the worker runs (docs/performance.md, "API under load").

Starts the real service (``rig serve --recording REC`` or ``--demo``, uvicorn on loopback, in a
child process; the LUT cache warm) replaying 1280×960 MJPEG frames at the recording's 30 fps, so
the depth worker runs flat out. Then, for 1, 8 and 32 concurrent clients (one keep-alive HTTP/1.1
connection each, all in this process's event loop; a minimal client, so that the clients' own
CPU stays small), ``GET /depth`` and then ``GET /health`` for ``--seconds`` each: every client
asks ``--rate`` times per second (default 10, a robot node consuming depth; 0 = back to back), at
most ``--max-requests`` times. Per phase: latency p50/p99 (request sent → body received),
requests per second, errors, the worker's fps (frames published during the phase, from
``/health``) against the idle fps (no clients) of the idle phases just before and after it,
and the CPU used by the service (from ``/proc``) and by the clients: on a 2-core machine the
clients compete with the service for the same cores.

Run: ``.venv/bin/python -m bench.api_load`` (``--quick`` for seconds).
"""

from __future__ import annotations

import argparse
import asyncio
import importlib.util
import math
import random
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
from rich.table import Table

from bench.common import (
    add_common_arguments,
    bench_cache_dir,
    console,
    finish,
    machine_info,
    median,
    print_machine,
    summary,
)
from bench.recordings import MjpegSpec, ensure_mjpeg_recording
from bench.service_proc import ServiceProcess, quick_serve_args

__all__ = ["Phase", "fps_drops", "main", "run_clients"]


@dataclass(frozen=True)
class Phase:
    clients: int
    endpoint: str
    latencies_ms: list[float]
    errors: int
    seconds: float
    worker_fps: float
    service_cpu_s: float
    client_cpu_s: float


async def _frames(client: httpx.AsyncClient, url: str) -> int:
    r = await client.get(url + "/health")
    return int(r.json()["worker"]["frames_processed"])


class _RawConnection:
    """A minimal keep-alive HTTP/1.1 client on asyncio streams: GET only, Content-Length bodies.

    The clients run on the same 2 cores as the service; httpx costs ~1 ms of CPU per request,
    this a small fraction of that, so the load measures the service rather than the client."""

    def __init__(self, host: str, port: int) -> None:
        self.host, self.port = host, port
        self._reader: asyncio.StreamReader | None = None
        self._writer: asyncio.StreamWriter | None = None

    async def get(self, path: str) -> tuple[int, int]:
        """(status, body length); reconnects when the server closed the connection."""
        if self._reader is None or self._writer is None or self._writer.is_closing():
            self._reader, self._writer = await asyncio.open_connection(self.host, self.port)
        reader, writer = self._reader, self._writer
        writer.write(f"GET {path} HTTP/1.1\r\nHost: {self.host}\r\n\r\n".encode())
        head = await reader.readuntil(b"\r\n\r\n")
        lines = head.decode("latin-1").split("\r\n")
        status = int(lines[0].split()[1])
        length = None
        for line in lines[1:]:
            name, _, value = line.partition(":")
            if name.strip().lower() == "content-length":
                length = int(value)
        if length is None:
            raise ValueError("response without Content-Length")
        body = await reader.readexactly(length)
        return status, len(body)

    async def close(self) -> None:
        if self._writer is not None:
            self._writer.close()


async def run_clients(
    url: str, endpoint: str, clients: int, seconds: float, rate: float, max_requests: int
) -> tuple[list[float], int]:
    """``clients`` concurrent loops of ``GET endpoint``, one keep-alive connection each;
    (latencies ms, failed requests)."""
    latencies: list[float] = []
    errors = 0
    host, port = httpx.URL(url).host, httpx.URL(url).port or 80
    deadline = time.perf_counter() + seconds

    async def one(k: int) -> None:
        nonlocal errors
        conn = _RawConnection(host, port)
        period = 1.0 / rate if rate > 0 else 0.0
        # Spread the clients over one period so they do not ask in lockstep.
        next_at = time.perf_counter() + (random.random() * period if period else 0.0)
        try:
            for _ in range(max_requests):
                now = time.perf_counter()
                if next_at > now:
                    await asyncio.sleep(next_at - now)
                if time.perf_counter() >= deadline:
                    return
                t0 = time.perf_counter()
                try:
                    status, size = await asyncio.wait_for(conn.get(endpoint), 10.0)
                    ok = status == 200 and size > 0
                except (OSError, ValueError, asyncio.IncompleteReadError, TimeoutError):
                    ok = False
                    await conn.close()
                    conn = _RawConnection(host, port)
                latencies.append((time.perf_counter() - t0) * 1e3)
                errors += not ok
                next_at = max(next_at + period, time.perf_counter()) if period else time.perf_counter()
        finally:
            await conn.close()

    await asyncio.gather(*(one(k) for k in range(clients)))
    return latencies, errors


async def _phase(
    svc: ServiceProcess, endpoint: str, clients: int, seconds: float, rate: float, max_requests: int
) -> Phase:
    async with httpx.AsyncClient(timeout=10.0) as probe:
        f0, c0, b0, t0 = await _frames(probe, svc.url), svc.cpu_s(), time.process_time(), time.monotonic()
        if clients:
            lat, errors = await run_clients(svc.url, endpoint, clients, seconds, rate, max_requests)
        else:
            lat, errors = [], 0
            await asyncio.sleep(seconds)
        f1, c1, b1, t1 = await _frames(probe, svc.url), svc.cpu_s(), time.process_time(), time.monotonic()
    return Phase(clients, endpoint, lat, errors, t1 - t0, (f1 - f0) / (t1 - t0), c1 - c0, b1 - b0)


async def _run(svc: ServiceProcess, args: argparse.Namespace, counts: list[int]) -> list[Phase]:
    """Loaded phases with an idle phase before and after each: the worker's rate drifts by a few
    percent over minutes, so each phase's fps drop is taken against its own neighbours."""
    idle_s = max(1.0, args.seconds / 2)
    phases = [await _phase(svc, "idle", 0, idle_s, 0, 0)]
    for n in counts:
        for endpoint in ("/depth", "/health"):
            phases.append(await _phase(svc, endpoint, n, args.seconds, args.rate, args.max_requests))
            phases.append(await _phase(svc, "idle", 0, idle_s, 0, 0))
    return phases


def fps_drops(phases: list[Phase]) -> list[float]:
    """Per phase: 1 − fps / mean fps of the idle phases next to it (0 for idle phases)."""
    drops = []
    for i, p in enumerate(phases):
        near = [q.worker_fps for q in phases[max(0, i - 1) : i + 2] if q.clients == 0 and q is not p]
        base = sum(near) / len(near) if near else math.nan
        drops.append(1.0 - p.worker_fps / base if p.clients and base > 0 else 0.0)
    return drops


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(prog="python -m bench.api_load", description=__doc__.split("\n\n")[0])
    add_common_arguments(parser)
    parser.add_argument("--clients", default="1,8,32", help="concurrent client counts")
    parser.add_argument("--seconds", type=float, default=None, help="length of each phase")
    parser.add_argument(
        "--rate", type=float, default=10.0, help="requests per second per client (0 = flat out)"
    )
    parser.add_argument("--max-requests", type=int, default=2000, help="most requests per client and phase")
    parser.add_argument("--demo", action="store_true", help="serve the built-in demo instead of MJPEG frames")
    parser.add_argument(
        "--png-compression", type=int, default=None, help="server.png_compression (default: the service's)"
    )
    parser.add_argument(
        "--recording", type=Path, default=None, help="serve this recording (default: bench's)"
    )
    args = parser.parse_args(argv)
    args.seconds = args.seconds or (1.5 if args.quick else 10.0)
    counts = [int(c) for c in args.clients.split(",")] if not args.quick else [1, 4]
    info = machine_info()
    print_machine(info, "HTTP API under load while the depth worker runs")
    if args.quick:
        serve_args = quick_serve_args()
        source = "the quick recording"
    elif args.demo:
        serve_args = ["--demo"]
        source = "the built-in demo"
    else:
        recording = args.recording or ensure_mjpeg_recording(MjpegSpec())
        serve_args = ["--recording", str(recording)]
        source = str(recording)
    if args.png_compression is not None:
        if args.quick:
            raise SystemExit("--png-compression is for full runs (--quick brings its own config)")
        config = bench_cache_dir() / f"api-load-png{args.png_compression}.yaml"
        config.parent.mkdir(parents=True, exist_ok=True)
        config.write_text(f"server: {{png_compression: {args.png_compression}}}\n")
        serve_args += ["--config", str(config)]
    env = {"RIG_CACHE_DIR": str(bench_cache_dir() / "lut")}
    console.print(
        f"service: rig serve {' '.join(serve_args)} ({source}); clients: {counts}, "
        f"{args.rate:g} req/s each (0 = flat out), {args.seconds:g} s per phase; uvicorn's "
        f"HTTP parser {_installed('httptools', 'h11')}, event loop {_installed('uvloop', 'asyncio')}"
    )
    with ServiceProcess([*serve_args, "--log-level", "warning"], env) as svc:
        ready_s = svc.wait_ready(600.0)
        time.sleep(0.5 if args.quick else 3.0)  # let the worker's rate settle
        phases = asyncio.run(_run(svc, args, counts))
        rss = svc.rss_mb()
    idle_fps = median(p.worker_fps for p in phases if p.clients == 0)
    table = Table(title=f"rig serve under load (idle worker fps {idle_fps:.2f}; ready after {ready_s:.1f} s)")
    for col in (
        "clients",
        "endpoint",
        "requests",
        "req/s",
        "p50 ms",
        "p99 ms",
        "max ms",
        "errors",
        "worker fps",
        "fps drop",
        "service CPU",
        "clients' CPU",
    ):
        table.add_column(col, justify="right")
    rows = []
    for p, drop in zip(phases, fps_drops(phases), strict=True):
        s = summary(p.latencies_ms)
        n = len(p.latencies_ms)
        row = {
            "clients": p.clients,
            "endpoint": p.endpoint,
            "requests": n,
            "req_per_s": n / p.seconds,
            "latency_ms": s,
            "errors": p.errors,
            "worker_fps": p.worker_fps,
            "fps_drop": drop,
            "service_cpu_s": p.service_cpu_s,
            "client_cpu_s": p.client_cpu_s,
        }
        rows.append(row)
        if not p.clients:
            continue
        table.add_row(
            str(p.clients),
            p.endpoint,
            str(n),
            f"{n / p.seconds:.0f}",
            f"{s['p50']:.1f}",
            f"{s['p99']:.1f}",
            f"{s['max']:.1f}",
            str(p.errors),
            f"{p.worker_fps:.2f}",
            f"{100 * drop:.1f}%",
            f"{100 * p.service_cpu_s / p.seconds:.0f}%",
            f"{100 * p.client_cpu_s / p.seconds:.0f}%",
        )
    idle_cpu = median(100 * p.service_cpu_s / p.seconds for p in phases if p.clients == 0)
    console.print(
        f"targets: /depth p99 ≤ 50 ms at 32 clients, worker fps drop ≤ 10%. CPU: % of one core "
        f"(the machine has {info['cpus']}); the idle service used {idle_cpu:.0f}%"
    )
    return finish(
        "api_load",
        info,
        {
            "source": source,
            "rate_per_client": args.rate,
            "seconds_per_phase": args.seconds,
            "ready_s": ready_s,
            "idle_fps": idle_fps,
            "rss_mb_end": rss,
            "phases": rows,
        },
        args.json,
        table,
    )


def _installed(fast: str, fallback: str) -> str:
    """The implementation uvicorn's "auto" picks: ``fast`` when it is installed."""
    return fast if importlib.util.find_spec(fast) is not None else fallback


if __name__ == "__main__":
    main()
