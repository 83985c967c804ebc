"""The service tests' one read-only app per module, in process (``shared_app``) or under a real
server where the socket is the subject (``shared_server``: streams); ``start_app``,
``start_server`` and the small recording are in tests/conftest.py."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import TypeVar

import pytest

from tests.helpers.service import InProcessServer, LiveServer, SmallRecording, service_settings

Served = TypeVar("Served", InProcessServer, LiveServer)


def _shared(kind: type[Served], recording: SmallRecording, lut_cache: Path, tmp: Path) -> Iterator[Served]:
    served = kind(service_settings(recording.loop, tmp, lut_cache)).start()
    try:
        served.wait_ready()
        yield served
    finally:
        served.stop()


@pytest.fixture(scope="module")
def shared_app(
    small_recording: SmallRecording, lut_cache: Path, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[InProcessServer]:
    """One app for the read-only tests of a module (nothing here may break its cameras or change
    its settings)."""
    yield from _shared(InProcessServer, small_recording, lut_cache, tmp_path_factory.mktemp("app"))


@pytest.fixture(scope="module")
def shared_server(
    small_recording: SmallRecording, lut_cache: Path, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[LiveServer]:
    """The same under a real server (uvicorn on loopback)."""
    yield from _shared(LiveServer, small_recording, lut_cache, tmp_path_factory.mktemp("srv"))
