"""Shared fixtures. Real third-party data lives in ../shared/data (never copied into the repo);
tests that need it skip with the reason when it is absent."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

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
