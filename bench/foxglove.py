"""The depth worker's frame rate with Foxglove viewers: none, one reading everything, and one that
subscribed to everything and then stopped reading (a dead or frozen viewer).

Starts the real service (``rig serve --recording REC``, uvicorn on loopback in a child process,
``server.foxglove`` on) replaying 1280×960 MJPEG frames at 30 fps, so the worker runs flat out.
Then alternates windows of ``--seconds``: no viewer; a viewer (in this process, the
foxglove.websocket.v1 client of the tests) subscribed to every topic and reading; a viewer
subscribed to every topic that never reads again (its connection's buffers fill, then the
server's per-viewer queue). Per window: the worker's frames per second (``/health``'s
``frames_processed`` over the window), the depth messages the reading viewer received per second,
the service's CPU use and resident memory. The figure to look at is the worker's fps drop in each
viewer window against the mean of the no-viewer windows on either side.

Run: ``.venv/bin/python -m bench.foxglove`` (``--quick`` for seconds).
"""

from __future__ import annotations

import argparse
import statistics
import threading
import time
from dataclasses import dataclass
from typing import Any

import httpx
from rich.table import Table

from bench.common import add_common_arguments, console, finish, machine_info, print_machine
from bench.recordings import MjpegSpec, ensure_mjpeg_recording
from bench.service_proc import ServiceProcess, free_port, quick_serve_args
from rig.ros.names import RosNames
from tests.service.foxglove_client import FoxgloveClient

PHASES = ("none", "reading", "stalled")


@dataclass
class Window:
    phase: str
    fps: float
    received_fps: float
    cpu: float
    rss_mb: float


def _processed(url: str) -> int:
    return int(httpx.get(url + "/health", timeout=5.0).json()["worker"]["frames_processed"])


def _all_topics(client: FoxgloveClient) -> list[str]:
    names = RosNames()
    client.wait_for_topics([names.depth_image, names.points])
    time.sleep(0.5)  # the rest are advertised with the same frame
    return sorted(t for t in client.channels if t != names.health)


class _Reader(threading.Thread):
    """Reads every message of a subscribed client, counting depth messages."""

    def __init__(self, client: FoxgloveClient) -> None:
        super().__init__(name="bench-foxglove-reader", daemon=True)
        self.client = client
        self.depth = 0
        self.stop = threading.Event()

    def run(self) -> None:
        depth_topic = RosNames().depth_image
        while not self.stop.is_set():
            try:
                topic, _, _ = self.client.next_message(1.0)
            except (TimeoutError, OSError):
                continue
            except Exception:
                return
            if topic == depth_topic:
                self.depth += 1


def _window(svc: ServiceProcess, phase: str, seconds: float, port: int) -> Window:
    client = FoxgloveClient(port) if phase != "none" else None
    reader = None
    if client is not None:
        client.subscribe(_all_topics(client))
        if phase == "reading":
            reader = _Reader(client)
            reader.start()
        time.sleep(1.0)  # subscriptions settle; a stalled viewer's buffers start filling
    n0, c0, t0 = _processed(svc.url), svc.cpu_s(), time.monotonic()
    d0 = reader.depth if reader is not None else 0
    time.sleep(seconds)
    n1, c1, t1 = _processed(svc.url), svc.cpu_s(), time.monotonic()
    received = (reader.depth - d0) / (t1 - t0) if reader is not None else 0.0
    rss = svc.rss_mb()
    if reader is not None:
        reader.stop.set()
    if client is not None:
        client.close()
    if reader is not None:
        reader.join(5.0)
    return Window(phase, (n1 - n0) / (t1 - t0), received, (c1 - c0) / (t1 - t0), rss)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(prog="python -m bench.foxglove", description=__doc__.split("\n\n")[0])
    add_common_arguments(parser)
    parser.add_argument("--seconds", type=float, default=None, help="length of each window")
    parser.add_argument("--max-fps", type=float, default=10.0, help="server.foxglove.max_fps")
    args = parser.parse_args(argv)
    seconds = args.seconds or (2.0 if args.quick else 10.0)
    repeat = args.repeat or (1 if args.quick else 3)
    info = machine_info()
    print_machine(info, "Foxglove viewers and the depth worker")
    full = ["--recording", str(ensure_mjpeg_recording(MjpegSpec()))] if not args.quick else []
    serve = quick_serve_args() if args.quick else full
    port = free_port()
    env = {
        "RIG_SERVER__FOXGLOVE__ENABLED": "true",
        "RIG_SERVER__FOXGLOVE__PORT": str(port),
        "RIG_SERVER__FOXGLOVE__MAX_FPS": str(args.max_fps),
    }
    windows: list[Window] = []
    with ServiceProcess(serve, env=env) as svc:
        svc.wait_ready(120.0)
        time.sleep(2.0)
        for _ in range(repeat):
            for phase in (*PHASES, "none"):
                if phase == "none" and windows and windows[-1].phase == "none":
                    continue
                windows.append(_window(svc, phase, seconds, port))
                console.print(f"{phase:8s} worker {windows[-1].fps:6.2f} fps", highlight=False)
    rows = []
    for i, w in enumerate(windows):
        if w.phase == "none":
            continue
        around = [x.fps for x in (windows[i - 1], windows[i + 1]) if x.phase == "none"]
        base = statistics.fmean(around)
        rows.append({**w.__dict__, "idle_fps": base, "drop_pct": 100.0 * (1.0 - w.fps / base)})
    table = Table(title=f"worker fps with Foxglove viewers ({seconds:g} s windows, max_fps {args.max_fps:g})")
    for col in (
        "viewer",
        "worker fps",
        "no-viewer fps",
        "drop",
        "depth msgs/s received",
        "service CPU",
        "RSS MiB",
    ):
        table.add_column(col, justify="right")
    for phase in PHASES[1:]:
        mine = [r for r in rows if r["phase"] == phase]
        table.add_row(
            phase,
            f"{statistics.median(r['fps'] for r in mine):.2f}",
            f"{statistics.median(r['idle_fps'] for r in mine):.2f}",
            f"{statistics.median(r['drop_pct'] for r in mine):+.1f} %",
            f"{statistics.median(r['received_fps'] for r in mine):.2f}" if phase == "reading" else "-",
            f"{statistics.median(r['cpu'] for r in mine):.2f}",
            f"{max(r['rss_mb'] for r in mine):.0f}",
        )
    idle_rss = max(w.rss_mb for w in windows if w.phase == "none")
    console.print(f"no-viewer windows: RSS up to {idle_rss:.0f} MiB")
    results = {
        "seconds": seconds,
        "max_fps": args.max_fps,
        "windows": [w.__dict__ for w in windows],
        "rows": rows,
    }
    return finish("foxglove", info, results, args.json, table)


if __name__ == "__main__":
    main()
