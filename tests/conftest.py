"""Shared fixtures (the helpers they use are in :mod:`tests.helpers`). Real third-party data
lives in ../shared/data (never copied into the repo); tests that need it skip with the reason
when it is absent."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.helpers.recordings import jpeg_copy
from tests.helpers.service import (
    LiveServer,
    SmallRecording,
    StartServer,
    render_small_recording,
    service_settings,
)

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("RIG_SHARED_DATA", REPO.parent / "shared" / "data"))


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """Root of the shared third-party data set; skips the test if it is not present."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"shared test data not found at {SHARED_DATA} (set RIG_SHARED_DATA)")
    return SHARED_DATA


def shared_file(relative: str) -> Path:
    """Path of one shared data file; skips the calling test if it is missing."""
    p = SHARED_DATA / relative
    if not p.exists():
        pytest.skip(f"shared test data file {p} not present")
    return p


@pytest.fixture(scope="session")
def lut_cache(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One LUT cache directory for the whole session: a table is built once, then loaded."""
    return tmp_path_factory.mktemp("lut-cache")


@pytest.fixture(scope="session")
def small_recording(tmp_path_factory: pytest.TempPathFactory) -> SmallRecording:
    """The demo room at half the prototype's size: 3 noisy pairs, 320x240 VPC, ground truth."""
    return render_small_recording(tmp_path_factory.mktemp("demo-small"))


@pytest.fixture(scope="session")
def jpeg_recording(small_recording: SmallRecording, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The small recording's 3 pairs re-encoded as JPEG, with the rig's calibration.yaml: what an
    MJPEG camera records (corrupt and truncated frames mean what they mean on a UVC camera)."""
    return jpeg_copy(small_recording.loop, tmp_path_factory.mktemp("jpeg-small") / "rec")


@pytest.fixture(scope="session")
def replayed_recording(small_recording: SmallRecording) -> Path:
    """What :func:`start_server` replays (the reliability suite overrides it with the JPEG copy)."""
    return small_recording.loop


@pytest.fixture
def start_server(replayed_recording: Path, lut_cache: Path, tmp_path: Path) -> Iterator[StartServer]:
    """Factory: a fresh server replaying :func:`replayed_recording` (keyword arguments as for
    ``service_settings``: ``server:`` fields, ``camera_faults``, ...), waited for until it serves
    depth unless ``ready=False``; stopped at teardown."""
    servers: list[LiveServer] = []

    def start(ready: bool = True, **kw: Any) -> LiveServer:
        live = LiveServer(service_settings(replayed_recording, tmp_path, lut_cache, **kw)).start()
        servers.append(live)
        if ready:
            live.wait_ready()
        return live

    yield start
    for live in servers:
        live.stop()
