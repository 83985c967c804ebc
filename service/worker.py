"""The depth worker: one thread taking the newest pair from the capture, running the pipeline and
publishing the result.

It asks the capture for the *newest* pair each time (older ones are counted as skipped by the
capture, never queued), so a slow pipeline drops frames instead of falling behind. Publishing is
a reference swap; clients encode what they need from the published result in their own threads.
A failing frame (corrupt image, wrong size) is counted and reported, and the worker goes on.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

from rig.capture.frame import FramePair
from rig.errors import RigError
from rig.pipeline import DepthPipeline
from service.store import FrameResult, ResultStore

__all__ = ["DepthWorker", "PairSource", "WorkerStats"]

log = logging.getLogger("service.worker")

STAGES = ("decode", "remap", "match", "refine", "filters", "depth", "total")


class PairSource(Protocol):
    def next_pair(self, timeout_s: float, *, newest: bool = True) -> FramePair | None: ...


@dataclass(frozen=True)
class WorkerStats:
    """Snapshot for /health and /metrics. ``fps`` over the last ``window_s``; ``stage_ms`` mean
    per stage over the recent frames; ``latency_ms`` mean processing time (decode → depth);
    ``age_ms`` mean time from a frame's arrival in this process to its result's publication."""

    alive: bool
    frames_processed: int
    errors: int
    last_error: str | None
    last_error_age_ms: float | None
    last_seq: int | None
    last_index: int
    last_result_age_ms: float | None
    fps: float
    latency_ms: float | None
    age_ms: float | None
    stage_ms: dict[str, float]


class DepthWorker:
    """Runs :meth:`DepthPipeline.process` on the newest pairs of ``source`` (see module doc).

    ``on_pair`` (e.g. the recorder) gets every pair the worker takes, before processing, and
    must not block; ``on_result`` gets each published result's stage timings (metrics).
    """

    def __init__(
        self,
        source: PairSource,
        pipeline: DepthPipeline,
        store: ResultStore,
        *,
        on_pair: Callable[[FramePair], None] | None = None,
        on_result: Callable[[FrameResult, dict[str, float]], None] | None = None,
        poll_s: float = 0.1,
        window_s: float = 2.0,
    ) -> None:
        self.source = source
        self.pipeline = pipeline
        self.store = store
        self._on_pair = on_pair
        self._on_result = on_result
        self._poll_s = poll_s
        self._window_ns = round(window_s * 1e9)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        self._recent: deque[tuple[int, dict[str, float], float]] = deque(maxlen=256)
        self._processed = 0
        self._errors = 0
        self._last_error: tuple[str, int] | None = None
        self._last_seq: int | None = None
        self._last_published_ns: int | None = None

    # ----- lifecycle ---------------------------------------------------------------------------
    def start(self) -> None:
        if self._thread is not None:
            return
        self._thread = threading.Thread(target=self._run, name="rig-depth-worker", daemon=True)
        self._thread.start()

    def stop(self, timeout_s: float = 10.0) -> None:
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout_s)

    def is_alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    # ----- loop --------------------------------------------------------------------------------
    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                pair = self.source.next_pair(self._poll_s, newest=True)
                if pair is None:
                    continue
                self._process(pair)
            except RigError as err:
                self._failed(str(err))
            except Exception as err:  # a bug must not kill the service's only worker
                log.exception("depth worker: unexpected error")
                self._failed(f"{type(err).__name__}: {err}")
                self._stop.wait(self._poll_s)

    def _process(self, pair: FramePair) -> None:
        if self._on_pair is not None:
            self._on_pair(pair)
        t0 = time.perf_counter()
        left, right = pair.left.image, pair.right.image  # decoded in the capture threads already
        decode_ms = (time.perf_counter() - t0) * 1e3
        frame = self.pipeline.process(left, right, pair.seq, pair.ts_ns)
        timings = {"decode": decode_ms, **frame.timings_ms}
        timings["total"] = frame.timings_ms.get("total", 0.0) + decode_ms
        now = time.monotonic_ns()
        arrived = max(pair.left.host_ns, pair.right.host_ns)
        with self._lock:
            self._processed += 1
            index = self._processed
        result = FrameResult(
            index=index,
            frame=frame,
            left=pair.left,
            right=pair.right,
            published_ns=now,
            latency_ms=(now - arrived) / 1e6,
            cache=self.store.new_cache(),
        )
        self.store.publish(result)
        with self._lock:
            self._recent.append((now, timings, result.latency_ms))
            self._last_seq = pair.seq
            self._last_published_ns = now
        if self._on_result is not None:
            self._on_result(result, timings)

    def _failed(self, message: str) -> None:
        with self._lock:
            self._errors += 1
            first = self._last_error is None or self._last_error[0] != message
            self._last_error = (message, time.monotonic_ns())
        if first:
            log.warning("depth worker: %s", message)

    # ----- stats -------------------------------------------------------------------------------
    def stats(self) -> WorkerStats:
        now = time.monotonic_ns()
        with self._lock:
            recent = [r for r in self._recent if now - r[0] <= self._window_ns]
            processed, errors, last_error = self._processed, self._errors, self._last_error
            last_seq, last_pub = self._last_seq, self._last_published_ns
        fps = 0.0
        if len(recent) > 1 and recent[-1][0] > recent[0][0]:
            fps = (len(recent) - 1) / ((recent[-1][0] - recent[0][0]) / 1e9)
        stage_ms: dict[str, float] = {}
        if recent:
            for stage in STAGES:
                values = [t[stage] for _, t, _ in recent if stage in t]
                if values:
                    stage_ms[stage] = sum(values) / len(values)
        return WorkerStats(
            alive=self.is_alive(),
            frames_processed=processed,
            errors=errors,
            last_error=None if last_error is None else last_error[0],
            last_error_age_ms=None if last_error is None else (now - last_error[1]) / 1e6,
            last_seq=last_seq,
            last_index=processed,
            last_result_age_ms=None if last_pub is None else (now - last_pub) / 1e6,
            fps=fps,
            latency_ms=stage_ms.get("total"),
            age_ms=(sum(r[2] for r in recent) / len(recent)) if recent else None,
            stage_ms=stage_ms,
        )
