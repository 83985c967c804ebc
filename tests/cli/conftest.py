"""Fixtures of the command-line tests: the service tests' small rendered recording (once per
session) and its JPEG copy (what an MJPEG camera records)."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.reliability.common import jpeg_copy
from tests.service.conftest import SmallRecording, small_recording

__all__ = ["jpeg_recording", "small_recording"]


@pytest.fixture(scope="session")
def jpeg_recording(small_recording: SmallRecording, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The small recording's 3 pairs re-encoded as JPEG, with the rig's calibration.yaml."""
    return jpeg_copy(small_recording.loop, tmp_path_factory.mktemp("cli-jpeg"))
