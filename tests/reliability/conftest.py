"""The reliability suite replays the small recording's JPEG copy (tests/conftest.py), so corrupt
and truncated frames mean what they mean on a UVC camera: 3 noisy pairs of the prototype rig at
half size (640x480 fisheyes), looping at 10 fps with a 320x240 VPC."""

from __future__ import annotations

from pathlib import Path

import pytest


@pytest.fixture(scope="session")
def replayed_recording(jpeg_recording: Path) -> Path:
    return jpeg_recording
