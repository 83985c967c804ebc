"""Resident memory of ``rig serve --demo`` over time (docs/performance.md, "Memory").

Starts the real service in a child process (``rig serve --demo``, or ``--recording REC``), waits
for its first depth frame, then samples its RSS (``/proc/PID/status`` VmRSS) every
``--interval`` seconds for ``--seconds`` (default 600) while a light client uses the API like
the dashboard does (``/depth``, ``/depth/colorized`` and ``/health`` in turn, ``--client-rate``
requests per second; 0 = none). Reports the peak, the RSS at the start and the end of the
measured window, and the growth as least-squares slopes (MiB/min): over the window after the
first ``--settle`` seconds, and over the second half of the run. The service keeps freed memory
for reuse (:func:`rig.heap.tune_allocator`), so RSS climbs to its working set during the
first minutes and then must stay flat: a leak shows as a slope in the second half.

RSS alone cannot tell a leak from memory the allocator keeps (a freed block's pages stay resident,
and fragmentation can raise the high-water mark in steps). So each sample also reads the service's
``/metrics``: ``rig_malloc_in_use_bytes`` (what malloc has handed out and not had back) and
``rig_python_allocated_blocks`` (Python objects' memory blocks), see :mod:`rig.heap`. Their slopes
over the second half (of each window's minimum, as a sample catches a varying share of one frame's
temporaries) are the leak test: a leak must show there, whatever RSS does.

Run: ``.venv/bin/python -m bench.memory`` (``--seconds 60`` to shorten, ``--quick`` for seconds).
"""

from __future__ import annotations

import argparse
import threading
import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np
from prometheus_client.parser import text_string_to_metric_families
from rich.table import Table

from bench.common import add_common_arguments, console, finish, machine_info, print_machine
from bench.service_proc import ServiceProcess, serve_args_for

__all__ = ["heap_sample", "main", "slope_mb_per_min", "window_minima"]

ENDPOINTS = ("/depth", "/depth/colorized", "/health")


def slope_mb_per_min(times_s: list[float], rss_mb: list[float]) -> float:
    """Least-squares slope of RSS over time, MiB per minute (0 for fewer than 2 samples)."""
    if len(times_s) < 2:
        return 0.0
    t = np.asarray(times_s, dtype=np.float64)
    y = np.asarray(rss_mb, dtype=np.float64)
    a = np.vstack([t, np.ones_like(t)]).T
    (k, _), *_ = np.linalg.lstsq(a, y, rcond=None)
    return float(k) * 60.0


def window_minima(points: list[tuple[float, float]], window_s: float) -> list[tuple[float, float]]:
    """``(time, value)`` points reduced to each ``window_s`` window's minimum, at the window's
    middle (windows counted from time 0; empty ones left out)."""
    windows: dict[int, float] = {}
    for t, v in points:
        k = int(t // window_s)
        windows[k] = min(v, windows.get(k, v))
    return [((k + 0.5) * window_s, v) for k, v in sorted(windows.items())]


# The service's heap figures (rig.heap, in /metrics) and the scale they are reported in:
# malloc's bytes in use in MiB, Python's memory blocks in thousands.
HEAP_METRICS: dict[str, float] = {
    "rig_malloc_in_use_bytes": 1.0 / (1 << 20),
    "rig_python_allocated_blocks": 1e-3,
}


def heap_sample(url: str) -> dict[str, float]:
    """The service's heap figures (:data:`HEAP_METRICS`) from its ``/metrics``; those it does not
    export (no glibc ``mallinfo2``) are missing."""
    text = httpx.get(url + "/metrics", timeout=10.0).text
    return {
        s.name: s.value
        for family in text_string_to_metric_families(text)
        for s in family.samples
        if s.name in HEAP_METRICS
    }


def _client(url: str, rate: float, stop: threading.Event, counts: dict[str, int]) -> None:
    with httpx.Client(base_url=url, timeout=10.0) as client:
        k = 0
        while not stop.is_set():
            endpoint = ENDPOINTS[k % len(ENDPOINTS)]
            k += 1
            try:
                ok = client.get(endpoint).status_code == 200
            except httpx.HTTPError:
                ok = False
            counts["ok" if ok else "failed"] += 1
            stop.wait(1.0 / rate)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(prog="python -m bench.memory", description=__doc__.split("\n\n")[0])
    add_common_arguments(parser)
    parser.add_argument("--seconds", type=float, default=None, help="measured time (default 600)")
    parser.add_argument("--interval", type=float, default=None, help="seconds between samples (default 5)")
    parser.add_argument(
        "--settle", type=float, default=None, help="seconds left out of the slope (default 60)"
    )
    parser.add_argument("--client-rate", type=float, default=2.0, help="API requests per second (0 = none)")
    parser.add_argument("--recording", type=Path, default=None, help="serve a recording instead of --demo")
    args = parser.parse_args(argv)
    seconds = args.seconds or (4.0 if args.quick else 600.0)
    interval = args.interval or (0.5 if args.quick else 5.0)
    settle = args.settle if args.settle is not None else (1.0 if args.quick else min(60.0, seconds / 5))
    info = machine_info()
    print_machine(info, "RSS of rig serve over time")
    serve_args = serve_args_for(args.quick, args.recording)
    console.print(
        f"service: rig serve {' '.join(serve_args)}; {seconds:g} s, a sample every {interval:g} s, "
        f"client {args.client_rate:g} req/s over {', '.join(ENDPOINTS)}"
    )
    samples: list[tuple[float, float]] = []
    heap: list[tuple[float, dict[str, float]]] = []
    counts = {"ok": 0, "failed": 0}
    with ServiceProcess([*serve_args, "--log-level", "warning"]) as svc:
        ready_s = svc.wait_ready(900.0)
        stop = threading.Event()
        client = None
        if args.client_rate > 0:
            client = threading.Thread(
                target=_client,
                args=(svc.url, args.client_rate, stop, counts),
                name="bench-client",
                daemon=True,
            )
            client.start()
        t0 = time.monotonic()
        try:
            while True:
                now = time.monotonic() - t0
                samples.append((now, svc.rss_mb()))
                heap.append((now, heap_sample(svc.url)))
                if now >= seconds:
                    break
                time.sleep(min(interval, max(0.0, seconds - now)))
            health = httpx.get(svc.url + "/health", timeout=10.0).json()
        finally:
            stop.set()
            if client is not None:
                client.join(15.0)
    times = [t for t, _ in samples]
    rss = [r for _, r in samples]
    window = [(t, r) for t, r in samples if t >= settle]
    slope = slope_mb_per_min([t for t, _ in window], [r for _, r in window])
    half = [(t, r) for t, r in samples if t >= times[-1] / 2]
    slope_half = slope_mb_per_min([t for t, _ in half], [r for _, r in half])
    peak = max(rss)
    # The heap's second-half slopes (MiB/min in use by malloc, thousand Python blocks per minute),
    # of each window's minimum: a sample catches a varying share of a frame's temporaries (tens
    # of MiB), the minimum is what stays held between them.
    window_s = min(60.0, seconds / 10)
    heap_half = [(t, h) for t, h in heap if t >= times[-1] / 2]
    heap_slopes = {}
    for name, scale in HEAP_METRICS.items():
        floors = window_minima([(t, h[name] * scale) for t, h in heap_half if name in h], window_s)
        if floors:
            heap_slopes[name] = slope_mb_per_min([t for t, _ in floors], [v for _, v in floors])
    table = Table(title=f"RSS of rig serve (ready after {ready_s:.1f} s)")
    for col in (
        "minute",
        "RSS MiB (min / max)",
        "malloc in use MiB (min / max)",
        "Python blocks k (min / max)",
    ):
        table.add_column(col, justify="right")
    minute = 0

    def span(values: list[float], scale: float) -> str:
        return f"{min(values) * scale:.1f} / {max(values) * scale:.1f}" if values else "-"

    while minute * 60 <= times[-1]:
        inside = [r for t, r in samples if minute * 60 <= t < (minute + 1) * 60]
        heap_in = [h for t, h in heap if minute * 60 <= t < (minute + 1) * 60]
        if inside:
            heap_spans = [span([h[n] for h in heap_in if n in h], s) for n, s in HEAP_METRICS.items()]
            table.add_row(str(minute), span(inside, 1.0), *heap_spans)
        minute += 1
    console.print(
        f"peak {peak:.1f} MiB, start {rss[0]:.1f} MiB, end {rss[-1]:.1f} MiB, growth {slope:+.3f} MiB/min "
        f"after the first {settle:g} s, {slope_half:+.3f} MiB/min over the second half; worker processed "
        f"{health['worker']['frames_processed']} frames ({health['worker']['fps']:.1f} fps at the end); "
        f"client requests ok {counts['ok']}, failed {counts['failed']}. Target: ≤ 300 MiB, no growth."
    )
    console.print(
        "second half, in use: malloc "
        + (
            f"{heap_slopes['rig_malloc_in_use_bytes']:+.3f} MiB/min"
            if "rig_malloc_in_use_bytes" in heap_slopes
            else "not exported (no glibc mallinfo2)"
        )
        + f", Python blocks {heap_slopes.get('rig_python_allocated_blocks', 0.0):+.3f} k/min "
        "(a leak grows these; RSS also moves with what the allocator keeps)"
    )
    return finish(
        "memory",
        info,
        {
            "serve_args": serve_args,
            "seconds": seconds,
            "ready_s": ready_s,
            "peak_mb": peak,
            "start_mb": rss[0],
            "end_mb": rss[-1],
            "slope_mb_per_min": slope,
            "slope_second_half_mb_per_min": slope_half,
            "settle_s": settle,
            "client_requests": counts,
            "frames_processed": health["worker"]["frames_processed"],
            "samples": samples,
            "heap_samples": heap,
            "heap_slopes_second_half": heap_slopes,
        },
        args.json,
        table,
    )


if __name__ == "__main__":
    main()
