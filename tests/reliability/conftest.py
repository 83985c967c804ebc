"""Fixtures of the reliability suite: the small rendered recording re-encoded as JPEG (once per
session, so corrupt and truncated JPEG frames mean what they mean on a UVC camera); the servers
of ``start_server`` (tests/conftest.py) replay it."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.helpers.recordings import jpeg_copy
from tests.helpers.service import SmallRecording


@pytest.fixture(scope="session")
def jpeg_recording(small_recording: SmallRecording, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """3 noisy pairs of the prototype rig at half size (640x480 fisheyes) as JPEG, with the
    rig's calibration.yaml; the service replays it looping at 10 fps with a 320x240 VPC."""
    return jpeg_copy(small_recording.loop, tmp_path_factory.mktemp("reliability") / "jpeg")


@pytest.fixture(scope="session")
def served_recording(jpeg_recording: Path) -> Path:
    return jpeg_recording
