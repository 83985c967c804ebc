"""The depth worker: takes the newest pair from the capture, runs the pipeline and publishes the
result, as a three-stage pipeline on three threads so that consecutive frames overlap on a
multi-core CPU (OpenCV and numpy release the GIL):

1. ``rig-depth-prepare``: take the newest pair, decode both frames' luma (unless the capture did)
   and remap them to the VPC pair, one frame per thread (:meth:`DepthPipeline.rectify_camera`);
2. ``rig-depth-match``: the stereo matcher (:meth:`DepthPipeline.match`);
3. ``rig-depth-worker``: refinement, filters, depth (:meth:`DepthPipeline.finish`) and publishing.

Stages hand over through one-item slots, so frame N+1 is remapped and frame N-1 refined while
frame N is matched. Frames stay fresh: the prepare stage takes a pair from the capture only *just
in time* — when the match stage is expected to be free by the time the pair is remapped — so a
slow pipeline drops older pairs in the capture (counted there as skipped) instead of holding a
stale one. Publishing is a reference swap; clients encode what they need from the published
result in their own threads. A failing frame is counted and reported, and the worker goes on: one
that does not decode against its camera (``frames_undecodable``), any other failure (a wrong
size, say) as the worker's error.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, Generic, Protocol, TypeVar

from numpy.typing import NDArray

from rig.capture.frame import Frame, FramePair
from rig.counters import Counts, Tally, complete
from rig.errors import CorruptFrameError, RigError
from rig.pipeline import DepthFrame, DepthPipeline, MatchedPair, RectifiedPair, VpcGeometry
from rig.priority import apply_to_current_thread
from service.store import PublishedResult, ResultStore

__all__ = ["DepthWorker", "PairSource", "WorkerStats", "render_vpc"]

log = logging.getLogger("service.worker")

STAGES = ("decode", "remap", "match", "refine", "filters", "depth", "total")
# Weight of the newest sample in the stage-time averages that time the just-in-time take.
_EMA_ALPHA = 0.2
# Start the prepare stage this much earlier than "just in time" (fraction of its time, + s).
_PREPARE_SLACK = 0.25
_PREPARE_SLACK_S = 0.0005

T = TypeVar("T")


class PairSource(Protocol):
    def next_pair(self, timeout_s: float, *, newest: bool = True) -> FramePair | None: ...

    def report_undecodable(self, frame: Frame, err: Exception) -> None:
        """A frame of a pair taken from this source did not decode (the camera's fault)."""


@dataclass(frozen=True)
class WorkerStats:
    """Snapshot for /health and /metrics: ``counters`` are the figures of group ``worker`` in
    :mod:`rig.counters` (``fps`` over the last ``window_s``; the means over the recent frames);
    ``stage_ms`` is the mean time per stage over the recent frames."""

    last_error: str | None
    last_error_age_ms: float | None
    last_seq: int | None
    last_index: int
    stage_ms: dict[str, float]
    counters: Counts

    @property
    def alive(self) -> bool:
        return bool(self.counters["alive"])


@dataclass
class _Prepared:
    pair: FramePair
    rect: RectifiedPair
    decode_ms: float


@dataclass
class _Matched:
    pair: FramePair
    matched: MatchedPair
    decode_ms: float


class _Slot(Generic[T]):
    """A one-item hand-off between two stage threads; waits give up when ``stop`` is set."""

    def __init__(self, stop: threading.Event, poll_s: float) -> None:
        self._stop = stop
        self._poll_s = poll_s
        self._cond = threading.Condition()
        self._item: T | None = None

    def put(self, item: T) -> bool:
        """Hand ``item`` over, waiting while the slot is full; False when stopped."""
        with self._cond:
            while self._item is not None:
                if self._stop.is_set():
                    return False
                self._cond.wait(self._poll_s)
            self._item = item
            self._cond.notify_all()
            return True

    def take(self, on_take: Callable[[], None] | None = None) -> T | None:
        """The item, waiting up to the poll interval; None if there was none. ``on_take`` runs
        under the slot's lock before a waiting producer is woken."""
        with self._cond:
            if self._item is None:
                self._cond.wait(self._poll_s)
            item, self._item = self._item, None
            if item is not None:
                if on_take is not None:
                    on_take()
                self._cond.notify_all()
            return item

    def wait_empty(self, start_at_ns: Callable[[], float]) -> None:
        """Wait until the slot is empty and ``time.monotonic_ns()`` has reached
        ``start_at_ns()`` (re-read whenever the slot changes), or the worker stops."""
        with self._cond:
            while not self._stop.is_set():
                now = time.monotonic_ns()
                if self._item is None:
                    wait_s = (start_at_ns() - now) / 1e9
                    if wait_s <= 0.0:
                        return
                else:
                    wait_s = self._poll_s
                self._cond.wait(min(self._poll_s, wait_s))

    def update(self, change: Callable[[], None]) -> None:
        """Run ``change`` under the slot's lock and wake the waiters (they re-read their state)."""
        with self._cond:
            change()
            self._cond.notify_all()

    def notify(self) -> None:
        with self._cond:
            self._cond.notify_all()


class _Ema:
    """Exponential moving average of a duration in ns (0 before the first sample)."""

    def __init__(self) -> None:
        self.value_ns = 0.0

    def add(self, ns: float) -> None:
        self.value_ns = ns if self.value_ns == 0.0 else self.value_ns + _EMA_ALPHA * (ns - self.value_ns)


def render_vpc(pipeline: DepthPipeline, camera: str, frame: Frame) -> NDArray[Any]:
    """The VPC image of ``camera`` (``left``/``right``) from its raw ``frame``'s full (colour)
    image: what :meth:`PublishedResult.vpc_image` asks for."""
    name = pipeline.names[0 if camera == "left" else 1]
    return pipeline.rectify_camera(name, frame.image)[0]


class DepthWorker:
    """Runs :class:`DepthPipeline` on the newest pairs of ``source`` (see module doc).

    ``on_pair`` (e.g. the recorder) gets every pair the worker takes, before processing, and
    must not block; ``on_result`` gets each published result's stage timings (metrics).
    ``prefetch`` maps response cache keys to their producers (e.g. ``"depth_png"`` → the 16-bit
    PNG): right after publishing a result the worker makes each encoding that clients asked for
    on the previous result, so clients polling the latest frame find its bytes ready instead of
    the first of them waiting for the encode (the per-key lock of the cache still means one
    encode per frame, whoever starts it).
    """

    def __init__(
        self,
        source: PairSource,
        pipeline: DepthPipeline,
        store: ResultStore,
        *,
        on_pair: Callable[[FramePair], None] | None = None,
        on_result: Callable[[PublishedResult, dict[str, float]], None] | None = None,
        poll_s: float = 0.1,
        window_s: float = 2.0,
        prefetch: Mapping[str, Callable[[PublishedResult], bytes]] | None = None,
    ) -> None:
        self.source = source
        self.pipeline = pipeline
        self.store = store
        self._on_pair = on_pair
        self._on_result = on_result
        self._poll_s = poll_s
        self._window_ns = round(window_s * 1e9)
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._decoder: ThreadPoolExecutor | None = None
        self._lock = threading.Lock()
        self._recent: deque[tuple[int, dict[str, float], float]] = deque(maxlen=256)
        self._counters = Tally("worker")  # under self._lock
        self._last_error: tuple[str, int] | None = None
        self._last_seq: int | None = None
        self._last_published_ns: int | None = None
        self._to_match: _Slot[_Prepared] = _Slot(self._stop, poll_s)
        self._to_finish: _Slot[_Matched] = _Slot(self._stop, poll_s)
        # Just-in-time take: when the match stage will be free, and how long preparing takes.
        self._prepare_time = _Ema()
        self._match_cycle = _Ema()
        self._match_free_ns = 0
        self._prefetch = dict(prefetch or {})
        self._previous: PublishedResult | None = None

    # ----- lifecycle ---------------------------------------------------------------------------
    def start(self) -> None:
        if self._threads:
            return
        self._decoder = ThreadPoolExecutor(
            max_workers=1, thread_name_prefix="rig-depth-decode", initializer=apply_to_current_thread
        )
        for name, target in (
            ("rig-depth-prepare", self._prepare_loop),
            ("rig-depth-match", self._match_loop),
            ("rig-depth-worker", self._finish_loop),
        ):
            thread = threading.Thread(target=self._guarded, args=(target,), name=name, daemon=True)
            self._threads.append(thread)
        for thread in self._threads:
            thread.start()

    def stop(self, timeout_s: float = 10.0) -> None:
        self._stop.set()
        self._to_match.notify()
        self._to_finish.notify()
        deadline = time.monotonic() + timeout_s
        for thread in self._threads:
            if thread is not threading.current_thread():
                thread.join(max(0.0, deadline - time.monotonic()))
        if self._decoder is not None:
            self._decoder.shutdown(wait=False, cancel_futures=True)

    def is_alive(self) -> bool:
        return bool(self._threads) and all(t.is_alive() for t in self._threads)

    # ----- stages ------------------------------------------------------------------------------
    def _guarded(self, step: Callable[[], None]) -> None:
        """Run one stage's step until stopped; a failing frame is counted, never fatal."""
        apply_to_current_thread()
        while not self._stop.is_set():
            try:
                step()
            except RigError as err:
                self._failed(str(err))
            except Exception as err:  # a bug must not kill the service's only worker
                log.exception("depth worker: unexpected error")
                self._failed(f"{type(err).__name__}: {err}")
                self._stop.wait(self._poll_s)

    def _start_prepare_at_ns(self) -> float:
        """Just in time: the match stage is expected free at ``_match_free_ns``; a pair taken
        now is ready after the prepare stage's usual time (plus some slack)."""
        lead = self._prepare_time.value_ns * (1.0 + _PREPARE_SLACK) + _PREPARE_SLACK_S * 1e9
        return self._match_free_ns - lead

    def _prepare_loop(self) -> None:
        self._to_match.wait_empty(self._start_prepare_at_ns)
        if self._stop.is_set():
            return
        pair = self.source.next_pair(self._poll_s, newest=True)
        if pair is None:
            return
        if self._on_pair is not None:
            self._on_pair(pair)
        t0 = time.perf_counter_ns()
        try:
            rect, decode_ms = self._rectify(pair)
        except CorruptFrameError:
            return  # counted against its camera (_luma); the worker itself is fine
        self._prepare_time.add(time.perf_counter_ns() - t0)
        self._to_match.put(_Prepared(pair, rect, decode_ms))

    def _rectify(self, pair: FramePair) -> tuple[RectifiedPair, float]:
        """Decode (where the capture did not) and remap one pair, the two frames on two threads."""
        pipe = self.pipeline
        left_name, right_name = pipe.names
        if self._decoder is None:
            t0 = time.perf_counter()
            left, right = self._luma(pair.left), self._luma(pair.right)
            decode_ms = (time.perf_counter() - t0) * 1e3
            return pipe.rectify(left, right), decode_ms
        # Each frame decoded (unless the capture did) and remapped on its own thread: JPEG
        # decoding is single-threaded, and two remaps at once beat one parallelised after another.
        # One geometry for both frames: a corrected calibration swapped in meanwhile
        # (DepthPipeline.replace_rig) starts with the next pair.
        geometry = pipe.geometry
        future: Future[tuple[NDArray[Any], NDArray[Any], float, float]] = self._decoder.submit(
            self._decode_rectify, left_name, pair.left, geometry
        )
        right_vpc, right_gray, right_decode, right_remap = self._decode_rectify(
            right_name, pair.right, geometry
        )
        left_vpc, left_gray, left_decode, left_remap = future.result()
        rect = RectifiedPair(
            left_vpc, right_vpc, left_gray, right_gray, max(left_remap, right_remap), geometry
        )
        return rect, max(left_decode, right_decode)

    def _decode_rectify(
        self, name: str, frame: Frame, geometry: VpcGeometry
    ) -> tuple[NDArray[Any], NDArray[Any], float, float]:
        t0 = time.perf_counter()
        image = self._luma(frame)
        t1 = time.perf_counter()
        vpc, gray = self.pipeline.rectify_camera(name, image, geometry)
        t2 = time.perf_counter()
        return vpc, gray, (t1 - t0) * 1e3, (t2 - t1) * 1e3

    def _luma(self, frame: Frame) -> NDArray[Any]:
        """The frame's luma (decoded now unless the capture thread did); a frame that does not
        decode is reported to the source, which counts it against its camera."""
        try:
            return frame.gray
        except CorruptFrameError as err:
            self.source.report_undecodable(frame, err)
            raise

    def _match_loop(self) -> None:
        t0 = 0

        def taken() -> None:  # under the slot's lock: the prepare stage sees it when it wakes
            nonlocal t0
            t0 = time.monotonic_ns()
            self._match_free_ns = round(t0 + self._match_cycle.value_ns)

        item = self._to_match.take(taken)
        if item is None:
            return
        try:
            matched = self.pipeline.match(item.rect)
            self._to_finish.put(_Matched(item.pair, matched, item.decode_ms))
        finally:
            # The cycle includes any wait for the finish stage: that is when it is free again.
            done = time.monotonic_ns()
            self._match_cycle.add(done - t0)

            def free() -> None:  # earlier than predicted: let the prepare stage start now
                self._match_free_ns = min(self._match_free_ns, done)

            self._to_match.update(free)

    def _finish_loop(self) -> None:
        item = self._to_finish.take()
        if item is None:
            return
        pair = item.pair
        frame = self.pipeline.finish(item.matched, pair.seq, pair.ts_ns)
        timings = {"decode": item.decode_ms, **frame.timings_ms}
        timings["total"] = frame.timings_ms.get("total", 0.0) + item.decode_ms
        self._publish(pair, frame, timings)

    def _publish(self, pair: FramePair, frame: DepthFrame, timings: dict[str, float]) -> None:
        arrived = max(pair.left.host_ns, pair.right.host_ns)
        with self._lock:
            self._counters.add("frames_processed")
            index = self._counters["frames_processed"]
        result = PublishedResult(
            index=index,
            frame=frame,
            left=pair.left,
            right=pair.right,
            published_ns=0,
            latency_ms=0.0,
            cache=self.store.new_cache(),
            render_vpc=functools.partial(render_vpc, self.pipeline),
        )
        # Encode what clients polled on the previous frame *before* this one becomes visible: a
        # poll then always finds its bytes ready (no request waits on the encode, none takes a
        # thread hop), for the price of that encode's time in every client's frame age.
        self._prefetch_for(result)
        now = time.monotonic_ns()
        result = dataclasses.replace(result, published_ns=now, latency_ms=(now - arrived) / 1e6)
        self._previous = result
        self.store.publish(result)
        with self._lock:
            self._recent.append((now, timings, result.latency_ms))
            self._last_seq = pair.seq
            self._last_published_ns = now
        if self._on_result is not None:
            self._on_result(result, timings)

    def _prefetch_for(self, result: PublishedResult) -> None:
        previous = self._previous
        if previous is None:
            return
        for key, produce in self._prefetch.items():
            if previous.cache.peek(key) is None:
                continue  # nobody asked for it lately
            try:
                result.cache.get(key, functools.partial(produce, result))
            except Exception as err:  # a client asking later gets the error itself
                log.debug("depth worker: prefetching %s failed: %s", key, err)

    def _failed(self, message: str) -> None:
        with self._lock:
            self._counters.add("errors")
            first = self._last_error is None or self._last_error[0] != message
            self._last_error = (message, time.monotonic_ns())
        if first:
            log.warning("depth worker: %s", message)

    # ----- stats -------------------------------------------------------------------------------
    def stats(self) -> WorkerStats:
        now = time.monotonic_ns()
        with self._lock:
            recent = [r for r in self._recent if now - r[0] <= self._window_ns]
            counted, last_error = self._counters.snapshot(), self._last_error
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
        measured = {
            **counted,
            "alive": self.is_alive(),
            "fps": fps,
            "latency_ms": stage_ms.get("total"),
            "age_ms": (sum(r[2] for r in recent) / len(recent)) if recent else None,
            "last_result_age_ms": None if last_pub is None else (now - last_pub) / 1e6,
        }
        return WorkerStats(
            last_error=None if last_error is None else last_error[0],
            last_error_age_ms=None if last_error is None else (now - last_error[1]) / 1e6,
            last_seq=last_seq,
            last_index=int(counted["frames_processed"] or 0),
            stage_ms=stage_ms,
            counters=complete("worker", measured),
        )
