"""The service under test: the small rendered recording it replays, its settings, and
``create_app(settings)`` either under a real uvicorn server in a thread on a free loopback port
(:class:`LiveServer`: where the socket, the connection limits, the HTTP parser or streams are
what is tested) or run in this process through httpx's ASGI transport (:class:`InProcessServer`:
the same ASGI app, lifespan, runtime, fast path, middleware and routes, without a socket). Both
give ``client`` (an ``httpx.Client`` on the service) and ``rig_client()``."""

from __future__ import annotations

import contextlib
import re
import socket
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import httpx
import numpy as np
import uvicorn
import yaml
from anyio.from_thread import BlockingPortal, start_blocking_portal
from prometheus_client.parser import text_string_to_metric_families

from bench.recordings import MjpegSpec
from rig.rectified import RectifiedPairConfig
from service.app import create_app
from service.client import RigClient
from service.demo import DemoSpec, render_demo
from service.runtime import Runtime
from service.serve import uvicorn_config
from service.settings import Settings, load_settings
from tests.helpers.recordings import FAST_SUPERVISOR
from tests.helpers.waiting import wait_for

__all__ = [
    "AUTH",
    "LOAD_REASONS",
    "QUICK_MJPEG",
    "REPLAY_FPS",
    "SMALL_SPEC",
    "TOKEN",
    "InProcessServer",
    "LiveServer",
    "SmallRecording",
    "StartApp",
    "StartServer",
    "in_process",
    "metric_values",
    "render_small_recording",
    "same_frame",
    "service_overrides",
    "service_settings",
    "small_recording_at",
    "write_serve_config",
]

TOKEN = "test-token-0123456789abcdef"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
#: Small and quick: 640x480 fisheyes (prototype rig at half size), 320x240 VPCs, 3 noisy frames.
# The ideal lens: these recordings serve the service's and the command's behaviour, not accuracy
# (through the honest lens the small pinhole pair has depth on 36 % of its pixels, not 56 %).
SMALL_SPEC = DemoSpec(
    scale=0.5, frames=3, supersample=1, vpc=RectifiedPairConfig(width=320, height=240), lens="ideal"
)
REPLAY_FPS = 10.0  # keeps the worker's CPU share low on a shared 2-core machine
#: What a loaded machine may turn /health degraded for (a camera thread or the worker starved of
#: CPU): frames dropped, no depth frame for a while. Anything else is a fault.
LOAD_REASONS = re.compile(r"camera (left|right): \d+ % of frames dropped .*|no depth frame for [\d.]+ s")
#: The quick benchmarks' colour MJPEG recording (bench.recordings): 4 pairs of the prototype rig at
#: quarter size (320x240 fisheyes), JPEG 4:2:2.
QUICK_MJPEG = MjpegSpec(frames=4, views=1, scale=0.25)


@dataclass(frozen=True)
class SmallRecording:
    loop: Path  # the replayed recording (3 noisy pairs + calibration.yaml)
    render: Path  # the noise-free render with ground_truth/
    gt_depth: np.ndarray  # float32 (240, 320) z in the left VPC frame, NaN = no surface


def render_small_recording(out: Path) -> SmallRecording:
    """The demo room rendered at :data:`SMALL_SPEC` into ``out``."""
    render_demo(SMALL_SPEC, out)
    return small_recording_at(out)


def small_recording_at(out: Path) -> SmallRecording:
    """The small recording :func:`render_small_recording` rendered into ``out``."""
    gt = np.load(out / "render" / "ground_truth" / "depth" / "000000.npy")
    return SmallRecording(out / "loop", out / "render", gt)


def service_overrides(
    recording: Path,
    tmp: Path,
    lut_cache: Path,
    *,
    fps: float = REPLAY_FPS,
    supervisor: dict[str, Any] | None = None,
    camera_faults: list[dict[str, Any]] | None = None,
    **server: Any,
) -> dict[str, Any]:
    """The settings document of a service replaying ``recording`` (looping, live timestamps) with
    a token, fault injection on, fast camera supervision, the small VPC, recordings under
    ``tmp/recordings`` and LUTs in ``lut_cache``; ``server`` overrides ``server:`` fields."""
    camera = {
        "kind": "file",
        "recording": str(recording),
        "pace": fps,
        "loop": True,
        "timestamps": "live",
        "faults": camera_faults or [],
    }
    return {
        "server": {
            "recordings_dir": str(tmp / "recordings"),
            "api_token": TOKEN,
            "fault_injection": True,
            **server,
        },
        "cameras": {
            "left": {**camera, "camera": "left"},
            "right": {**camera, "camera": "right"},
            "supervisor": supervisor if supervisor is not None else FAST_SUPERVISOR.model_dump(),
        },
        "rectified": SMALL_SPEC.vpc.model_dump(),
        "stereo": {"disparity_range": 64},
        "cache_dir": str(lut_cache),
    }


def service_settings(recording: Path, tmp: Path, lut_cache: Path, **kw: Any) -> Settings:
    """:func:`service_overrides` as validated Settings (for an in-process :class:`LiveServer`)."""
    return load_settings(None, service_overrides(recording, tmp, lut_cache, **kw))


def write_serve_config(path: Path, recording: Path, tmp: Path, lut_cache: Path, **kw: Any) -> Path:
    """:func:`service_overrides` as a YAML config file for ``rig serve --config``."""
    path.write_text(yaml.safe_dump(service_overrides(recording, tmp, lut_cache, **kw)))
    return path


class _Served:
    """What both ways of serving the app share: ``settings``, ``app``, ``client``, the runtime
    the lifespan built, waiting for the first depth frame."""

    settings: Settings
    app: Any
    client: httpx.Client
    base_url: str

    @property
    def runtime(self) -> Runtime:
        runtime: Runtime = self.app.state.runtime
        return runtime

    def wait_ready(self, timeout_s: float = 30.0) -> None:
        wait_for(
            lambda: self.client.get("/readyz").status_code == 200,
            timeout_s,
            "the first depth frame",
            poll_s=0.05,
        )


class LiveServer(_Served):
    """``create_app(settings)`` under a real uvicorn server in a thread, on 127.0.0.1:<free port>.
    ``lifespan="off"`` serves the app without ever building its runtime (routes may be added to
    ``app`` before :meth:`start`)."""

    def __init__(
        self, settings: Settings, runtime: Runtime | None = None, *, lifespan: Literal["on", "off"] = "on"
    ) -> None:
        self.settings = settings
        self.app = create_app(settings, runtime=runtime)
        # IPPROTO_TCP so asyncio sets TCP_NODELAY on accepted connections (as `rig serve` does).
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM, socket.IPPROTO_TCP)
        self.sock.bind(("127.0.0.1", 0))
        self.port = self.sock.getsockname()[1]
        self.base_url = f"http://127.0.0.1:{self.port}"
        # The configuration rig serve runs with (parser, connection limits), as the settings say.
        config = uvicorn_config(self.app, settings, "warning", lifespan=lifespan)
        self.server = uvicorn.Server(config)
        self.thread = threading.Thread(target=self.server.run, kwargs={"sockets": [self.sock]}, daemon=True)
        self.client = httpx.Client(base_url=self.base_url)

    def start(self, timeout_s: float = 60.0) -> LiveServer:
        self.thread.start()

        def started() -> bool:
            if not self.thread.is_alive():
                raise RuntimeError("uvicorn stopped before it started")
            return bool(self.server.started)

        wait_for(started, timeout_s, "uvicorn to start")
        return self

    def rig_client(self, token: str | None = None) -> RigClient:
        return RigClient(self.base_url, token=token)

    def stop(self) -> None:
        self.client.close()
        self.server.should_exit = True
        self.thread.join(20)
        self.sock.close()


class InProcessServer(_Served):
    """``create_app(settings)`` run in this process, without a socket: an event loop in a thread
    (anyio's blocking portal) runs the app's lifespan, which builds and starts the runtime as
    under uvicorn, and each request of :attr:`client` is one ASGI call of the app through httpx's
    own ``ASGITransport``, the fast path included (it is part of the app). As from a server,
    errors are answered (500), not raised into the test. Responses are whole bodies: streams that
    do not end, limits and timeouts are a real server's subject (:class:`LiveServer`)."""

    base_url = "http://testserver"

    def __init__(self, settings: Settings, runtime: Runtime | None = None) -> None:
        self.settings = settings
        self.app = create_app(settings, runtime=runtime)
        self._transport = _AppTransport(self.app)
        self.client = httpx.Client(base_url=self.base_url, transport=self._transport)
        self._running = contextlib.ExitStack()

    def start(self) -> InProcessServer:
        portal = self._running.enter_context(start_blocking_portal())
        self._running.enter_context(
            portal.wrap_async_context_manager(self.app.router.lifespan_context(self.app))
        )
        self._transport.portal = portal
        return self

    def rig_client(self, token: str | None = None) -> RigClient:
        """The typed client on the same app."""
        return RigClient(self.base_url, token=token, transport=self._transport)

    def stop(self) -> None:
        self.client.close()
        self._running.close()  # the lifespan's shutdown (the runtime stopped), then the loop


@contextlib.contextmanager
def in_process(
    settings: Settings, before_start: Callable[[Any], None] | None = None
) -> Iterator[InProcessServer]:
    """An :class:`InProcessServer` of ``settings``, started (``before_start(app)`` first: a
    middleware an embedding application adds, say) and stopped at the end."""
    server = InProcessServer(settings)
    if before_start is not None:
        before_start(server.app)
    server.start()
    try:
        yield server
    finally:
        server.stop()


class _AppTransport(httpx.BaseTransport):
    """httpx's ``ASGITransport`` for a synchronous client: each request is awaited in the app's
    event-loop thread (``portal``) and its whole body read there."""

    def __init__(self, app: Any) -> None:
        self._asgi = httpx.ASGITransport(app, raise_app_exceptions=False)
        self.portal: BlockingPortal | None = None

    def handle_request(self, request: httpx.Request) -> httpx.Response:
        if self.portal is None:
            raise RuntimeError("the in-process app is not started")
        return self.portal.call(self._call, request)

    async def _call(self, request: httpx.Request) -> httpx.Response:
        response = await self._asgi.handle_async_request(request)
        body = await response.aread()
        return httpx.Response(response.status_code, headers=response.headers, stream=httpx.ByteStream(body))


#: The ``start_server`` fixture's factory (tests/conftest.py): keyword arguments as for
#: :func:`service_settings`, plus ``ready`` (wait for the first depth frame, default True).
StartServer = Callable[..., LiveServer]
#: The ``start_app`` fixture's factory: the same, run in process.
StartApp = Callable[..., InProcessServer]


def metric_values(text: str) -> dict[tuple[str, tuple[tuple[str, str], ...]], float]:
    """``{(sample name, sorted labels): value}`` of a Prometheus text exposition."""
    out = {}
    for family in text_string_to_metric_families(text):
        for s in family.samples:
            out[(s.name, tuple(sorted(s.labels.items())))] = s.value
    return out


def same_frame(fetch_a: Callable[[], Any], fetch_b: Callable[[], Any], tries: int = 30) -> tuple[Any, Any]:
    """Two responses of the same frame (the worker publishes new frames all the time)."""
    for _ in range(tries):
        a, b = fetch_a(), fetch_b()
        if a.seq == b.seq:
            return a, b
    raise AssertionError("could not fetch two responses of one frame")
