"""Row bands: a row-local image computation split into horizontal bands across a thread pool.

OpenCV and numpy release the GIL, so on a multi-core CPU bands of one frame run at once; that
shortens a stage on every frame's critical path (its CPU time stays the same, plus the margins).
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Executor, Future
from typing import Any, TypeVar

__all__ = ["BandFn", "run_in_bands", "submit_or_run"]

T = TypeVar("T")

BandFn = Callable[[int, int, int, int], None]
"""``fn(a, b, r0, r1)``: compute output rows ``[r0, r1)`` from input rows ``[a, b)``."""


def run_in_bands(fn: BandFn, height: int, bands: int, margin: int, pool: Executor | None) -> None:
    """Call ``fn(a, b, r0, r1)`` for ``bands`` bands covering rows ``[0, height)``, with input
    rows ``[a, b) = [r0 - margin, r1 + margin)`` clipped to the image, so that every output row
    sees the neighbourhood it would see in one pass over the whole image. The calling thread runs
    the last band itself; with no ``pool`` (or one band) it is one call ``fn(0, height, 0, height)``.
    ``fn`` must only write its own output rows. Exceptions of any band are raised here."""
    step = -(-height // max(1, bands))
    if pool is None or step >= height:
        fn(0, height, 0, height)
        return
    spans = [
        (max(0, r0 - margin), min(height, r0 + step + margin), r0, min(height, r0 + step))
        for r0 in range(0, height, step)
    ]
    futures = [submit_or_run(pool, fn, *span) for span in spans[:-1]]
    try:
        fn(*spans[-1])
    finally:
        for future in futures:
            future.result()


def submit_or_run(pool: Executor | None, fn: Callable[..., T], *args: Any) -> Future[T]:
    """``pool.submit(fn, *args)``; or, with no pool or one shut down meanwhile (the finish
    stage's pool is replaced when the depth threads' priority changes), ``fn(*args)`` run here,
    its result or exception in a done future."""
    if pool is not None:
        try:
            return pool.submit(fn, *args)
        except RuntimeError:
            pass
    done: Future[T] = Future()
    try:
        done.set_result(fn(*args))
    except Exception as err:
        done.set_exception(err)
    return done
