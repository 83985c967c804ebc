"""The process's heap: glibc malloc tuned for per-frame temporaries, and what it holds.

:func:`tune_allocator` makes malloc keep freed frame-sized blocks for reuse (the pipeline calls it).
Because of that the resident size (RSS) climbs to the working set's high-water mark and stays
there, so RSS alone cannot tell a leak from memory kept for reuse. :func:`heap_stats` can: the
bytes malloc has handed out and not had back (``mallinfo2``), the bytes it keeps free for reuse, and
the number of memory blocks Python's own allocator holds (``sys.getallocatedblocks``). A leak makes
the in-use figures grow; fragmentation only moves bytes between "free" and the OS. ``/metrics``
exports them.
"""

from __future__ import annotations

import ctypes
import functools
import logging
import sys
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, cast

__all__ = ["HeapStats", "heap_stats", "tune_allocator"]

log = logging.getLogger(__name__)

# glibc mallopt parameters (malloc.h) and the values tune_allocator sets.
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD, _M_ARENA_MAX = -1, -3, -8
_MMAP_THRESHOLD_BYTES = 32 << 20  # glibc's largest allowed value on 64-bit
_TRIM_THRESHOLD_BYTES = 256 << 20
_allocator_tuned: bool | None = None
_allocator_lock = threading.Lock()


@functools.cache
def _libc_function(name: str, argtypes: tuple[Any, ...], restype: Any) -> Any:
    """The C library's function ``name`` typed for ctypes, or None where there is none (not
    Linux, or not glibc). Looked up once per name."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        fn = getattr(ctypes.CDLL(None), name)
    except (OSError, AttributeError):
        return None
    fn.argtypes = list(argtypes)
    fn.restype = restype
    return fn


def tune_allocator() -> bool:
    """Make glibc's malloc keep freed memory for reuse (once per process; True if done).

    Every frame allocates and frees dozens of MB-sized numpy/OpenCV temporaries. By default
    glibc returns such blocks to the kernel at once (mmap above 128 KiB, heap trimming, one arena
    per thread), so the next frame's temporaries are fresh pages and each page costs a page fault:
    measured on a 2-core VM, refinement took 21 ms of CPU instead of 8 and a 10 k-element multiply
    30 µs instead of 2. This sets ``M_MMAP_THRESHOLD`` to 32 MiB, ``M_TRIM_THRESHOLD`` to 256 MiB
    and one arena (thread arenas ignore the thresholds), so the process keeps its working set
    (RSS stays at its peak instead of breathing). Process-wide: call it before starting threads.
    A no-op (False) where the C library has no ``mallopt`` (not glibc).
    """
    global _allocator_tuned
    with _allocator_lock:
        if _allocator_tuned is not None:
            return _allocator_tuned
        _allocator_tuned = False
        mallopt = _libc_function("mallopt", (ctypes.c_int, ctypes.c_int), ctypes.c_int)
        if mallopt is None:
            return False
        done = all(
            mallopt(param, value) == 1
            for param, value in (
                (_M_ARENA_MAX, 1),
                (_M_MMAP_THRESHOLD, _MMAP_THRESHOLD_BYTES),
                (_M_TRIM_THRESHOLD, _TRIM_THRESHOLD_BYTES),
            )
        )
        _allocator_tuned = done
        log.debug("malloc tuned for reuse of large temporaries: %s", done)
        return done


class _Mallinfo2(ctypes.Structure):
    """glibc's ``struct mallinfo2`` (malloc.h, glibc ≥ 2.33): every field a size_t."""

    _fields_ = [
        (name, ctypes.c_size_t)
        for name in (
            "arena",
            "ordblks",
            "smblks",
            "hblks",
            "hblkhd",
            "usmblks",
            "fsmblks",
            "uordblks",
            "fordblks",
            "keepcost",
        )
    ]


def _mallinfo2() -> Callable[[], _Mallinfo2] | None:
    """glibc's ``mallinfo2``, or None (not glibc, or glibc older than 2.33)."""
    return cast(Callable[[], _Mallinfo2] | None, _libc_function("mallinfo2", (), _Mallinfo2))


@dataclass(frozen=True)
class HeapStats:
    """``malloc_in_use_bytes``: handed out by malloc and not freed (heap chunks in use plus
    mmapped blocks); ``malloc_free_bytes``: freed, kept by malloc for reuse (not given back to the
    OS); both None where the C library has no ``mallinfo2`` (not glibc ≥ 2.33).
    ``python_blocks``: memory blocks currently allocated by Python's object allocator."""

    malloc_in_use_bytes: int | None
    malloc_free_bytes: int | None
    python_blocks: int


def heap_stats() -> HeapStats:
    """The process's heap now (see :class:`HeapStats`). ``mallinfo2`` walks malloc's free lists:
    fine for a scrape every few seconds, not for a per-frame hook."""
    mallinfo2 = _mallinfo2()
    blocks = sys.getallocatedblocks()
    if mallinfo2 is None:
        return HeapStats(None, None, blocks)
    info = mallinfo2()
    return HeapStats(int(info.uordblks) + int(info.hblkhd), int(info.fordblks), blocks)
