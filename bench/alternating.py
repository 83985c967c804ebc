"""The service's worker and the floor in alternating short windows of one run (``bench.worker``).

This VM's speed drifts by 20–30 % between minutes. A floor run followed by a separately built
runtime a few seconds later compares two different machines, and single ratios scattered ±20 %.
Here one runtime (the service's own, on file cameras) stays up for a whole figure and is
*paused* between its windows: its worker's pair source sits behind a gate (:class:`GatedPairs`),
so with the gate shut the worker idles and the floor runs alone (unpaced cameras block under
back-pressure after one pair; paced ones go on and the capture keeps only the newest pair, as
it does for a busy worker). Each ratio then compares windows seconds apart, and the order
alternates (ours then floor, floor then ours) so that a steady drift cancels.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from types import TracebackType

from rig.capture.frame import Frame, FramePair, FrameSet
from service.runtime import Runtime
from service.settings import Settings
from service.store import PublishedResult
from service.worker import PairSource

__all__ = ["GatedPairs", "Window", "WorkerSession"]

# A window's first results come from a pipeline filling up (and a paced pair that waited at the
# gate): skip this many before timing.
SETTLE_RESULTS = 3


class GatedPairs:
    """A :class:`service.worker.PairSource` passing pairs only while :attr:`open` is set."""

    def __init__(self, source: PairSource) -> None:
        self.source = source
        self.open = threading.Event()

    def next_pair(self, timeout_s: float, *, newest: bool = True) -> FramePair | None:
        if not self.open.wait(timeout_s):
            return None
        return self.source.next_pair(timeout_s, newest=newest)

    def next_set(self, timeout_s: float, *, newest: bool = True) -> FrameSet | None:
        if not self.open.wait(timeout_s):
            return None
        return self.source.next_set(timeout_s, newest=newest)

    def report_undecodable(self, frame: Frame, err: Exception) -> None:
        self.source.report_undecodable(frame, err)


@dataclass(frozen=True)
class Window:
    """One timed window of ours: published pairs per second between its first and last timed
    results, process CPU per pair, cores kept busy (CPU time / wall time), each timed result's
    latency (pair arrival → published, ms) and the worker's mean stage times."""

    fps: float
    frames: int
    cpu_ms: float
    cores: float
    latency_ms: list[float]
    stage_ms: dict[str, float]
    errors: int


class WorkerSession:
    """The service's runtime on ``settings``, started once and timed in windows
    (:meth:`window`) with the gate shut in between; a client thread notes every result's
    latency, as ``/stream`` would see it. A context manager."""

    def __init__(self, settings: Settings) -> None:
        self.runtime = Runtime.build(settings)
        self.gate = GatedPairs(self.runtime.worker.source)
        # The bench pauses the worker through its source: the worker reads it on every take.
        self.runtime.worker.source = self.gate
        self._published: list[tuple[int, float]] = []  # (published_ns, latency_ms) per result
        self._done = threading.Event()
        self._watcher = threading.Thread(target=self._watch, name="bench-watch", daemon=True)

    def _watch(self) -> None:
        index = 0
        while not self._done.is_set():
            result = self.runtime.store.wait_newer(index, 0.2)
            if result is not None:
                index = result.index
                self._published.append((result.published_ns, result.age_ms))

    def __enter__(self) -> WorkerSession:
        self.runtime.start()
        self._watcher.start()
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self._done.set()
        self.gate.open.set()  # a worker waiting at the gate must see the stop
        self.runtime.stop()
        self._watcher.join(2.0)

    def _index(self) -> int:
        latest = self.runtime.store.latest
        return 0 if latest is None else latest.index

    def _errors(self) -> int:
        """The worker's error count (an int counter of :mod:`rig.counters`)."""
        return int(self.runtime.worker.stats().counters["errors"] or 0)

    def _next_result(self, index: int, timeout_s: float) -> PublishedResult:
        result = self.runtime.store.wait_newer(index, timeout_s)
        if result is None:
            raise RuntimeError(f"the worker published nothing in {timeout_s:g} s")
        return result

    def window(self, seconds: float, timeout_s: float = 30.0) -> Window:
        """Open the gate, skip :data:`SETTLE_RESULTS` results, time ``seconds``, shut the gate
        and wait until the pairs in flight are published (so the next floor window runs alone)."""
        errors0 = self._errors()
        self.gate.open.set()
        try:
            first = self._next_result(self._index(), timeout_s)
            for _ in range(SETTLE_RESULTS - 1):
                first = self._next_result(first.index, timeout_s)
            c0, t0 = time.process_time(), time.monotonic()
            time.sleep(seconds)
            c1, t1 = time.process_time(), time.monotonic()
            last = self.runtime.store.latest
        finally:
            self.gate.open.clear()
        assert last is not None
        stage_ms = dict(self.runtime.worker.stats().stage_ms)
        frames = last.index - first.index
        span_s = (last.published_ns - first.published_ns) / 1e9
        fps = frames / span_s if frames and span_s > 0 else 0.0
        cores = (c1 - c0) / (t1 - t0)
        self._drain(fps)
        # After the drain: the watcher has seen every result up to ``last`` by now.
        latencies = [ms for ns, ms in self._published if first.published_ns < ns <= last.published_ns]
        errors = self._errors() - errors0
        cpu_ms = cores / fps * 1e3 if fps else float("nan")
        return Window(fps, frames, cpu_ms, cores, latencies, stage_ms, errors)

    def _drain(self, fps: float) -> None:
        """Wait until no result has come for a few frame times (the pipeline is empty)."""
        quiet_s = max(0.3, 3.0 / fps) if fps else 1.0
        index = self._index()
        while (result := self.runtime.store.wait_newer(index, quiet_s)) is not None:
            index = result.index
