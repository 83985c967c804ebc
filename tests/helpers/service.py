"""The service under test: the small rendered recording it replays, its settings, and
``create_app(settings)`` under a real uvicorn server in a thread on a free loopback port."""

from __future__ import annotations

import socket
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import httpx
import numpy as np
import uvicorn
import yaml
from prometheus_client.parser import text_string_to_metric_families

from rig.rectified import RectifiedPairConfig
from service.app import create_app
from service.demo import DemoSpec, render_demo
from service.runtime import Runtime
from service.serve import uvicorn_config
from service.settings import Settings, load_settings
from tests.helpers.recordings import FAST_SUPERVISOR
from tests.helpers.waiting import wait_for

__all__ = [
    "AUTH",
    "REPLAY_FPS",
    "SMALL_SPEC",
    "TOKEN",
    "LiveServer",
    "SmallRecording",
    "StartServer",
    "metric_values",
    "render_small_recording",
    "same_frame",
    "service_overrides",
    "service_settings",
    "write_serve_config",
]

TOKEN = "test-token-0123456789abcdef"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
#: Small and quick: 640x480 fisheyes (prototype rig at half size), 320x240 VPCs, 3 noisy frames.
# The ideal lens: these recordings serve the service's and the command's behaviour, not accuracy
# (through the honest lens the small pinhole pair has depth on 36 % of its pixels, not 56 %).
SMALL_SPEC = DemoSpec(scale=0.5, frames=3, supersample=1, vpc=RectifiedPairConfig(width=320, height=240), lens="ideal")
REPLAY_FPS = 10.0  # keeps the worker's CPU share low on a shared 2-core machine


@dataclass(frozen=True)
class SmallRecording:
    loop: Path  # the replayed recording (3 noisy pairs + calibration.yaml)
    render: Path  # the noise-free render with ground_truth/
    gt_depth: np.ndarray  # float32 (240, 320) z in the left VPC frame, NaN = no surface


def render_small_recording(out: Path) -> SmallRecording:
    """The demo room rendered at :data:`SMALL_SPEC` into ``out``."""
    loop = render_demo(SMALL_SPEC, out)
    gt = np.load(out / "render" / "ground_truth" / "depth" / "000000.npy")
    return SmallRecording(loop, out / "render", gt)


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
        "vpc": SMALL_SPEC.vpc.model_dump(),
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


class LiveServer:
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

    def start(self, timeout_s: float = 60.0) -> LiveServer:
        self.thread.start()

        def started() -> bool:
            if not self.thread.is_alive():
                raise RuntimeError("uvicorn stopped before it started")
            return bool(self.server.started)

        wait_for(started, timeout_s, "uvicorn to start")
        return self

    @property
    def runtime(self) -> Runtime:
        runtime: Runtime = self.app.state.runtime
        return runtime

    def wait_ready(self, timeout_s: float = 30.0) -> None:
        wait_for(
            lambda: httpx.get(self.base_url + "/readyz").status_code == 200,
            timeout_s,
            "the first depth frame",
            poll_s=0.05,
        )

    def stop(self) -> None:
        self.server.should_exit = True
        self.thread.join(20)
        self.sock.close()


#: The ``start_server`` fixture's factory (tests/conftest.py): keyword arguments as for
#: :func:`service_settings`, plus ``ready`` (wait for the first depth frame, default True).
StartServer = Callable[..., LiveServer]


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
