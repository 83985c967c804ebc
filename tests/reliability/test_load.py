"""Load: 32 concurrent loopback clients for 15 s against ``rig serve`` (a real subprocess, so the
clients do not share its interpreter) on ``/depth``, ``/health`` and ``/stream.mjpg``: no errors,
every ``/health`` poll answered and never down (degraded only for what a starved machine causes:
frames dropped, a depth frame late; never a worker, capture or calibration error), the depth worker
keeps producing, and the server's memory stays bounded and under the memory budget it exports
(``rig_memory_budget_bytes``).

Memory bound: the service keeps the latest result and its encoded bodies (a few hundred kB at
320x240), per-connection buffers and the allocator's working set; after a warm-up with every
client connected once and the rectification monitor's first check done (it builds its epipolar
views once; docs/rectification.md), that is its steady state, which moves by a few MB in steps
(allocator high-water marks: one run grew 10.8 MB over 10,554 requests, another 0.2 MB over
21,681). The window is three windows of 5 s: a leak grows RSS in every one of them by what it
leaks per request times the requests served there, a high-water step in one. So at least one
window must grow by less than 1 kB per request it served (a per-request leak of 1 kB fails),
and the whole run by less than 50 MB.
"""

from __future__ import annotations

import asyncio
import re
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import pytest

from tests.helpers.command import Served, clean_env, start_serve, wait_healthy
from tests.helpers.service import LOAD_REASONS, write_serve_config
from tests.helpers.waiting import wait_for

# Alone (make test runs it after the parallel suite): the load it judges is its own 32 clients',
# not the other workers' tests beside them (docs/development.md, "Markers").
pytestmark = [pytest.mark.slow, pytest.mark.alone, pytest.mark.timeout(600)]

DURATION_S = 15.0
WINDOWS = 3  # the leak check's windows, DURATION_S / WINDOWS each
WARMUP_S = 5.0
DEPTH_CLIENTS = 12
HEALTH_CLIENTS = 12
STREAM_CLIENTS = 8  # half read a few parts and hang up, half let the server end a short stream
MAX_RSS_GROWTH_MB = 50.0
LEAK_PER_REQUEST_MB = 1024 / 2**20  # 1 kB
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
BOUNDARY = b"--frame\r\n"


@dataclass
class Tally:
    requests: dict[str, int] = field(default_factory=lambda: {"depth": 0, "health": 0, "stream": 0})
    parts: int = 0
    errors: list[str] = field(default_factory=list)
    statuses: Counter[str] = field(default_factory=Counter)
    reasons: Counter[str] = field(default_factory=Counter)


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    raise AssertionError(f"no VmRSS for pid {pid}")


async def depth_client(base: str, until: float, tally: Tally) -> None:
    async with httpx.AsyncClient(base_url=base, timeout=15) as c:
        while time.monotonic() < until:
            try:
                r = await c.get("/depth")
                if r.status_code != 200 or not r.content.startswith(PNG_SIGNATURE):
                    tally.errors.append(f"/depth {r.status_code}")
                int(r.headers["X-Frame-Seq"])
                tally.requests["depth"] += 1
            except (httpx.HTTPError, KeyError, ValueError) as err:
                tally.errors.append(f"/depth {type(err).__name__}: {err}")


async def health_client(base: str, until: float, tally: Tally) -> None:
    async with httpx.AsyncClient(base_url=base, timeout=15) as c:
        while time.monotonic() < until:
            try:
                r = await c.get("/health")
                doc = r.json()
                tally.statuses[doc["status"]] += 1
                tally.reasons.update(re.sub(r"[\d.]+", "N", reason) for reason in doc["reasons"])
                unexpected = [reason for reason in doc["reasons"] if not LOAD_REASONS.fullmatch(reason)]
                if r.status_code != 200 or doc["status"] not in ("ok", "degraded") or unexpected:
                    tally.errors.append(f"/health {r.status_code} {doc['status']}: {doc['reasons']}")
                tally.requests["health"] += 1
            except (httpx.HTTPError, KeyError, ValueError) as err:
                tally.errors.append(f"/health {type(err).__name__}: {err}")


async def stream_client(base: str, until: float, tally: Tally, hang_up: bool) -> None:
    """Reads 3 parts per connection: either hangs up after them or lets the server end the
    stream (``max_frames=3``); then reconnects."""
    async with httpx.AsyncClient(base_url=base, timeout=15) as c:
        while time.monotonic() < until:
            params = {} if hang_up else {"max_frames": 3}
            try:
                async with c.stream("GET", "/stream.mjpg", params=params) as r:
                    if r.status_code != 200:
                        tally.errors.append(f"/stream.mjpg {r.status_code}")
                        continue
                    data = b""
                    async for chunk in r.aiter_bytes():
                        data += chunk
                        if hang_up and data.count(BOUNDARY) >= 4:  # 3 whole parts and the next head
                            break
                parts = data.count(BOUNDARY)
                if parts < 3 or b"Content-Type: image/jpeg" not in data:
                    tally.errors.append(f"/stream.mjpg: {parts} parts")
                tally.parts += min(parts, 3)
                tally.requests["stream"] += 1
            except httpx.HTTPError as err:
                tally.errors.append(f"/stream.mjpg {type(err).__name__}: {err}")


async def run_clients(base: str, seconds: float) -> Tally:
    tally = Tally()
    until = time.monotonic() + seconds
    tasks = [depth_client(base, until, tally) for _ in range(DEPTH_CLIENTS)]
    tasks += [health_client(base, until, tally) for _ in range(HEALTH_CLIENTS)]
    tasks += [stream_client(base, until, tally, hang_up=k % 2 == 0) for k in range(STREAM_CLIENTS)]
    await asyncio.gather(*tasks)
    return tally


def merged(windows: list[Tally]) -> Tally:
    out = Tally()
    for w in windows:
        out.requests = {k: out.requests[k] + w.requests[k] for k in out.requests}
        out.parts += w.parts
        out.errors += w.errors
        out.statuses += w.statuses
        out.reasons += w.reasons
    return out


def healthy(base: str) -> dict[str, Any] | None:
    doc: dict[str, Any] = httpx.get(base + "/health", timeout=10).json()
    return doc if doc["status"] == "ok" else None


def monitor_checked(base: str) -> bool:
    rect = httpx.get(base + "/health", timeout=10).json()["rectification"]
    return rect is None or rect["checks"] >= 1


@pytest.fixture
def served(jpeg_recording: Path, lut_cache: Path, tmp_path: Path) -> Served:
    # The supervisor as deployed (defaults), not the tests' fast-reacting one.
    cfg = write_serve_config(
        tmp_path / "serve.yaml", jpeg_recording, tmp_path, lut_cache, port=0, supervisor={}
    )
    s = start_serve(["--config", str(cfg), "--log-level", "warning"], clean_env(tmp_path))
    try:
        wait_healthy(s.url, 60)
    except AssertionError:
        s.stop()
        raise
    return s


def test_32_clients_for_15_s(served: Served) -> None:
    base = served.url.rstrip("/")
    pid = served.proc.pid
    try:
        warm = asyncio.run(run_clients(base, WARMUP_S))
        assert not warm.errors, warm.errors[:5]
        wait_for(lambda: monitor_checked(base), 60, "the rectification monitor's first check", poll_s=0.5)
        worker_before = httpx.get(base + "/health", timeout=10).json()["worker"]["frames_processed"]
        rss = [rss_mb(pid)]
        windows: list[Tally] = []
        for _ in range(WINDOWS):
            windows.append(asyncio.run(run_clients(base, DURATION_S / WINDOWS)))
            rss.append(rss_mb(pid))
        tally = merged(windows)
        # Once the load is over, a degraded episode ends (frame rates are judged over a window).
        h = wait_for(lambda: healthy(base), 60, "/health ok after the load", poll_s=0.5)
        metrics = httpx.get(base + "/metrics", timeout=10).text
        budget_mb = next(
            float(line.split()[1]) / 2**20
            for line in metrics.splitlines()
            if line.startswith("rig_memory_budget_bytes ")
        )
        assert served.proc.poll() is None  # still running
    finally:
        text = served.stop()
    print(
        f"\n{sum(tally.requests.values())} requests in {DURATION_S:.0f} s {tally.requests}, "
        f"{tally.parts} stream parts, {len(tally.errors)} errors; /health {dict(tally.statuses)} "
        f"{dict(tally.reasons)}; RSS {' -> '.join(f'{mb:.1f}' for mb in rss)} MiB "
        f"(windows of {[sum(w.requests.values()) for w in windows]} requests) "
        f"(budget {budget_mb:.0f} MiB); "
        f"worker {h['worker']['frames_processed'] - worker_before} frames at {h['worker']['fps']:.1f} fps"
    )
    assert not tally.errors, tally.errors[:10]
    assert tally.statuses["ok"] > 0 and set(tally.statuses) <= {"ok", "degraded"}
    assert min(tally.requests.values()) > 0 and tally.parts > 0
    assert h["status"] == "ok" and h["worker"]["alive"] and h["worker"]["fps"] > 0
    assert h["worker"]["frames_processed"] > worker_before  # it kept producing under load
    growth = [
        (after - before, sum(w.requests.values()) * LEAK_PER_REQUEST_MB)
        for before, after, w in zip(rss[:-1], rss[1:], windows, strict=True)
    ]
    assert any(grew < leak for grew, leak in growth), growth  # (MB grown, MB a 1 kB leak adds) per window
    assert rss[-1] - rss[0] < MAX_RSS_GROWTH_MB
    assert rss[-1] < budget_mb  # the budget rig serve exports (service.memory)
    assert served.proc.returncode == 0 and "Traceback" not in text
