"""Fixtures of the reliability suite: a small rendered recording re-encoded as JPEG (once per
session, so corrupt and truncated JPEG frames mean what they mean on a UVC camera), a LUT cache,
and real uvicorn servers (the service tests' :class:`LiveServer`) replaying it."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from service.demo import render_demo
from tests.reliability.common import jpeg_copy, service_settings
from tests.service.conftest import SMALL_SPEC, LiveServer


@pytest.fixture(scope="session")
def jpeg_recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """3 noisy pairs of the prototype rig at half size (640x480 fisheyes) as JPEG, with the
    rig's calibration.yaml; the service replays it looping at 10 fps with a 320x240 VPC."""
    out = tmp_path_factory.mktemp("reliability-render")
    png_loop = render_demo(SMALL_SPEC, out)
    return jpeg_copy(png_loop, out / "jpeg")


@pytest.fixture(scope="session")
def lut_cache(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("reliability-lut-cache")


@pytest.fixture
def start_server(
    jpeg_recording: Path, lut_cache: Path, tmp_path: Path
) -> Iterator[Callable[..., LiveServer]]:
    """Factory: a fresh server on the JPEG recording (``service_settings`` keyword overrides),
    waited for until it serves depth unless ``ready=False``; stopped at teardown."""
    servers: list[LiveServer] = []

    def start(ready: bool = True, **kw: Any) -> LiveServer:
        live = LiveServer(service_settings(jpeg_recording, tmp_path, lut_cache, **kw)).start()
        servers.append(live)
        if ready:
            live.wait_ready()
        return live

    yield start
    for live in servers:
        live.stop()
