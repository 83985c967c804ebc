"""Fixtures for the service tests: a small rendered recording (once per session) and real uvicorn
servers on loopback running ``create_app`` on it."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
import uvicorn

from rig.vpc import VpcConfig
from service.app import create_app
from service.demo import DemoSpec, render_demo
from service.runtime import Runtime
from service.settings import Settings, load_settings

TOKEN = "test-token-0123456789abcdef"
#: Small and quick: 640x480 fisheyes (prototype rig at half size), 320x240 VPCs, 3 noisy frames.
SMALL_SPEC = DemoSpec(scale=0.5, frames=3, supersample=1, vpc=VpcConfig(width=320, height=240))
REPLAY_FPS = 10.0  # keeps the worker's CPU share low on a shared 2-core machine
# Fast camera supervision so faults show within a fraction of a second.
FAST_SUPERVISOR = {"watchdog_s": 0.3, "reconnect_after_s": 1.0, "read_timeout_s": 0.05, "backoff_max_s": 0.2}


@dataclass(frozen=True)
class SmallRecording:
    loop: Path  # the replayed recording (3 noisy pairs + calibration.yaml)
    render: Path  # the noise-free render with ground_truth/
    gt_depth: np.ndarray  # float32 (240, 320) z in the left VPC frame, NaN = no surface


@pytest.fixture(scope="session")
def small_recording(tmp_path_factory: pytest.TempPathFactory) -> SmallRecording:
    out = tmp_path_factory.mktemp("demo-small")
    loop = render_demo(SMALL_SPEC, out)
    gt = np.load(out / "render" / "ground_truth" / "depth" / "000000.npy")
    return SmallRecording(loop, out / "render", gt)


@pytest.fixture(scope="session")
def lut_cache(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("lut-cache")


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
    a token, fault injection on, the small VPC, and recordings under ``tmp/recordings``."""
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
            "supervisor": supervisor if supervisor is not None else FAST_SUPERVISOR,
        },
        "vpc": SMALL_SPEC.vpc.model_dump(),
        "stereo": {"disparity_range": 64},
        "cache_dir": str(lut_cache),
    }


def small_settings(
    rec: SmallRecording,
    tmp: Path,
    lut_cache: Path,
    camera_faults: list[dict[str, Any]] | None = None,
    **server: Any,
) -> Settings:
    return load_settings(
        None, service_overrides(rec.loop, tmp, lut_cache, camera_faults=camera_faults, **server)
    )


class LiveServer:
    """``create_app(settings)`` under a real uvicorn server in a thread, on 127.0.0.1:<free port>."""

    def __init__(self, settings: Settings, runtime: Runtime | None = None) -> None:
        self.settings = settings
        self.app = create_app(settings, runtime=runtime)
        # IPPROTO_TCP so asyncio sets TCP_NODELAY on accepted connections (as `rig serve` does).
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM, socket.IPPROTO_TCP)
        self.sock.bind(("127.0.0.1", 0))
        self.port = self.sock.getsockname()[1]
        self.base_url = f"http://127.0.0.1:{self.port}"
        config = uvicorn.Config(self.app, log_level="warning", timeout_graceful_shutdown=2, lifespan="on")
        self.server = uvicorn.Server(config)
        self.thread = threading.Thread(target=self.server.run, kwargs={"sockets": [self.sock]}, daemon=True)

    def start(self, timeout_s: float = 60.0) -> LiveServer:
        self.thread.start()
        deadline = time.monotonic() + timeout_s
        while not self.server.started:
            if not self.thread.is_alive() or time.monotonic() > deadline:
                raise RuntimeError("uvicorn did not start")
            time.sleep(0.02)
        return self

    @property
    def runtime(self) -> Runtime:
        runtime: Runtime = self.app.state.runtime
        return runtime

    def wait_ready(self, timeout_s: float = 30.0) -> None:
        wait_for(
            lambda: httpx.get(self.base_url + "/readyz").status_code == 200, timeout_s, "first depth frame"
        )

    def stop(self) -> None:
        self.server.should_exit = True
        self.thread.join(20)
        self.sock.close()


def wait_for(predicate: Callable[[], bool], timeout_s: float, what: str, poll_s: float = 0.05) -> None:
    deadline = time.monotonic() + timeout_s
    while True:
        if predicate():
            return
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
        time.sleep(poll_s)


@pytest.fixture
def start_server(
    small_recording: SmallRecording, lut_cache: Path, tmp_path: Path
) -> Iterator[Callable[..., LiveServer]]:
    """Factory: a fresh server on the small recording (server settings as keyword overrides)."""
    servers: list[LiveServer] = []

    def start(
        ready: bool = True, camera_faults: list[dict[str, Any]] | None = None, **server: Any
    ) -> LiveServer:
        settings = small_settings(small_recording, tmp_path, lut_cache, camera_faults, **server)
        live = LiveServer(settings).start()
        servers.append(live)
        if ready:
            live.wait_ready()
        return live

    yield start
    for live in servers:
        live.stop()


@pytest.fixture(scope="module")
def shared_server(
    small_recording: SmallRecording, lut_cache: Path, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[LiveServer]:
    """One server for the read-only tests of a module (nothing here may break its cameras)."""
    live = LiveServer(small_settings(small_recording, tmp_path_factory.mktemp("srv"), lut_cache)).start()
    live.wait_ready()
    yield live
    live.stop()
