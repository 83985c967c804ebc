"""The benchmarks' generated inputs go to the session's bench cache (tests/conftest.py), not the
user's cache."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from bench.common import BENCH_CACHE_ENV


@pytest.fixture()
def bench_env(bench_cache: Path, lut_cache: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """Bench inputs in the session's bench cache; child services' LUTs in the session's LUT cache."""
    monkeypatch.setenv(BENCH_CACHE_ENV, str(bench_cache))
    monkeypatch.setenv("RIG_CACHE_DIR", str(lut_cache))
    yield bench_cache
