"""The recording attacks of :mod:`bench.hostile`: ``/health`` beside an active recording of
thousands of files (``recording``), and ``GET /recordings`` beside what a crash and careless hands
leave in the recordings directory (``listing``)."""

from __future__ import annotations

import argparse
import asyncio
import os
import shutil
import time
from pathlib import Path
from typing import Any

import httpx

from bench.common import summary as stats_of
from bench.hostile_clients import HealthProbe
from bench.service_proc import ServiceProcess

__all__ = ["AUTH", "TOKEN", "attack_listing", "attack_recording"]

TOKEN = "hostile-bench-token-0123456789"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


async def attack_recording(svc: ServiceProcess, args: argparse.Namespace) -> dict[str, Any]:
    host, port = "127.0.0.1", svc.port
    name = f"hostile-{os.getpid()}-{int(time.time())}"
    async with httpx.AsyncClient(timeout=60.0, headers=AUTH) as c:
        r = await c.post(svc.url + "/recordings", json={"name": name})
        r.raise_for_status()
        path = Path(r.json()["path"])
        try:
            extra = path / "extra"
            extra.mkdir()
            for k in range(args.files):
                (extra / f"{k:06d}.bin").touch()
            probes = [HealthProbe(host, port, period_s=0.0).start() for _ in range(4)]
            await asyncio.sleep(args.recording_s)
            results = [await p.stop() for p in probes]
            await c.post(svc.url + f"/recordings/{name}/stop")
        finally:
            shutil.rmtree(path, ignore_errors=True)
    lat = sorted(x for p in probes for x in p.latencies_s)
    s = stats_of([x * 1e3 for x in lat])
    return {
        "files": args.files,
        "health_p50_ms": s["p50"],
        "health_p95_ms": s["p95"],
        "requests": s["n"],
        "failures": sum(r["failures"] for r in results),
    }


async def attack_listing(svc: ServiceProcess, args: argparse.Namespace) -> dict[str, Any]:
    """``GET /recordings`` with a recording a crash left (``--files`` frame files, never stopped)
    and one with a malformed recording.json beside the service's own."""
    stamp = f"{os.getpid()}-{int(time.time())}"
    async with httpx.AsyncClient(timeout=120.0, headers=AUTH) as c:
        r = await c.post(svc.url + "/recordings", json={"name": f"hostile-{stamp}"})
        r.raise_for_status()
        own = Path(r.json()["path"])
        await c.post(svc.url + f"/recordings/hostile-{stamp}/stop")
        crashed, malformed = own.parent / f"crashed-{stamp}", own.parent / f"malformed-{stamp}"
        try:
            (crashed / "frames").mkdir(parents=True)
            (crashed / "recording.json").write_text('{"cameras": ["left", "right"]}')
            (crashed / "frames.csv").write_text("seq,left_ts_ns,right_ts_ns,left_file,right_file\n")
            for k in range(args.files):
                (crashed / "frames" / f"{k:06d}.jpg").touch()
            malformed.mkdir()
            (malformed / "recording.json").write_text('{"dropped": "many"}')
            statuses, seconds = [], []
            async with httpx.AsyncClient(timeout=120.0) as lister:  # c's connection idled meanwhile
                shown: dict[str, Any] = {}
                for _ in range(args.listings):
                    t0 = time.monotonic()
                    try:
                        r = await lister.get(svc.url + "/recordings")
                    except httpx.HTTPError:
                        statuses.append(0)  # no answer
                        continue
                    seconds.append(time.monotonic() - t0)
                    statuses.append(r.status_code)
                    shown = {e["name"]: e for e in r.json()} if r.status_code == 200 else shown
        finally:
            for path in (own, crashed, malformed):
                shutil.rmtree(path, ignore_errors=True)
    s = stats_of([x * 1e3 for x in seconds])
    return {
        "files": args.files,
        "statuses": {str(k): statuses.count(k) for k in sorted(set(statuses))},
        "listing_p50_ms": s["p50"],
        "listing_max_ms": s["max"],
        "malformed_entry": shown.get(f"malformed-{stamp}", {}).get("error"),
    }
