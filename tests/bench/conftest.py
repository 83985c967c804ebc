"""The benchmarks' generated inputs go to a per-session directory, not the user's cache."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from bench.common import BENCH_CACHE_ENV


@pytest.fixture(scope="session")
def bench_cache(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("bench-cache")


@pytest.fixture()
def bench_env(bench_cache: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """Bench cache in the session directory; the LUT cache of child services in ``tmp_path``."""
    monkeypatch.setenv(BENCH_CACHE_ENV, str(bench_cache))
    monkeypatch.setenv("RIG_CACHE_DIR", str(tmp_path / "lut"))
    yield bench_cache
