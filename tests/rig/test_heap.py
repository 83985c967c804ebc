"""rig.heap: the heap figures /metrics exports move with what the process really holds."""

from __future__ import annotations

import gc

import numpy as np
import pytest

import rig.pipeline
from rig.heap import heap_stats, tune_allocator

MIB = 1 << 20
# mallinfo2 counts the whole process: what other threads of the test process (pools and servers
# of earlier tests) free meanwhile may offset a reading by that much (seen: 272 bytes).
CHURN = 64 << 10


def _malloc_in_use() -> int:
    value = heap_stats().malloc_in_use_bytes
    if value is None:
        pytest.skip("this C library has no mallinfo2 (needs glibc >= 2.33)")
    return value


@pytest.mark.parametrize("mib", [1, 64])  # below and above the tuned mmap threshold (32 MiB)
def test_malloc_in_use_follows_an_allocation_and_its_release(mib: int) -> None:
    tune_allocator()
    before = _malloc_in_use()
    block = np.ones(mib * MIB, dtype=np.uint8)
    held = _malloc_in_use()
    del block
    after = _malloc_in_use()
    assert held - before >= mib * MIB - CHURN
    assert held - after >= mib * MIB - CHURN
    free = heap_stats().malloc_free_bytes
    assert free is not None and free >= 0


def test_python_blocks_count_live_objects() -> None:
    gc.collect()
    before = heap_stats().python_blocks
    objects = [object() for _ in range(50_000)]
    held = heap_stats().python_blocks
    del objects
    gc.collect()
    after = heap_stats().python_blocks
    assert held - before >= 50_000
    assert held - after >= 50_000


def test_pipeline_keeps_exporting_tune_allocator() -> None:
    assert rig.pipeline.tune_allocator is tune_allocator
