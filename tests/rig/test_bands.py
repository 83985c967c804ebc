"""rig.bands.run_in_bands: every output row exactly once, margins clipped to the image, and the
work still done when the pool has been shut down (replaced) meanwhile; submit_or_run likewise."""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor

import pytest

from rig.bands import run_in_bands, submit_or_run


def _record(height: int, bands: int, margin: int, pool: ThreadPoolExecutor | None) -> list[tuple[int, ...]]:
    calls: list[tuple[int, ...]] = []
    lock = threading.Lock()

    def fn(a: int, b: int, r0: int, r1: int) -> None:
        with lock:
            calls.append((a, b, r0, r1))

    run_in_bands(fn, height, bands, margin, pool)
    return sorted(calls, key=lambda c: c[2])


@pytest.mark.parametrize(("height", "bands", "margin"), [(480, 2, 9), (481, 4, 7), (10, 3, 20), (5, 8, 1)])
def test_bands_cover_every_row_once_with_clipped_margins(height: int, bands: int, margin: int) -> None:
    with ThreadPoolExecutor(2) as pool:
        calls = _record(height, bands, margin, pool)
    rows = [r for _, _, r0, r1 in calls for r in range(r0, r1)]
    assert rows == list(range(height))
    for a, b, r0, r1 in calls:
        assert a == max(0, r0 - margin) and b == min(height, r1 + margin)


def test_no_pool_is_one_call() -> None:
    assert _record(100, 4, 5, None) == [(0, 100, 0, 100)]


def test_a_shut_down_pool_still_gets_every_band_done() -> None:
    pool = ThreadPoolExecutor(2)
    pool.shutdown()
    calls = _record(100, 4, 3, pool)
    assert [c[2:] for c in calls] == [(0, 25), (25, 50), (50, 75), (75, 100)]


def test_submit_or_run_runs_here_without_a_live_pool() -> None:
    def where(x: int) -> tuple[int, str]:
        return x * 2, threading.current_thread().name

    with ThreadPoolExecutor(1, thread_name_prefix="pool") as pool:
        assert submit_or_run(pool, where, 3).result() == (6, "pool_0")
    here = threading.current_thread().name
    for gone in (None, pool):  # no pool; the pool shut down
        done = submit_or_run(gone, where, 4)
        assert done.done() and done.result() == (8, here)

    def fail() -> None:
        raise ValueError("bad band")

    failed = submit_or_run(None, fail)  # raised where the result is asked for, as from a pool
    with pytest.raises(ValueError, match="bad band"):
        failed.result()
