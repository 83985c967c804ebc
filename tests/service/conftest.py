"""The service tests' one read-only server per module (``start_server`` and the small recording
are in tests/conftest.py)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.helpers.service import LiveServer, SmallRecording, service_settings


@pytest.fixture(scope="module")
def shared_server(
    small_recording: SmallRecording, lut_cache: Path, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[LiveServer]:
    """One server for the read-only tests of a module (nothing here may break its cameras)."""
    live = LiveServer(
        service_settings(small_recording.loop, tmp_path_factory.mktemp("srv"), lut_cache)
    ).start()
    live.wait_ready()
    yield live
    live.stop()
