"""Staged depth: the pipeline's stages on their own threads, so that consecutive pairs overlap on
a multi-core CPU (OpenCV and numpy release the GIL). :class:`StagedExecutor` is the one executor
of depth: the service's worker, ``rig process`` (here or as cluster tasks) and ``rig export mcap``
all run it, each with its own source of pairs and its own :data:`Sink`::

    take → prepare → [slot] → match → [slot] → postprocess (→ [slot] → sink)

1. ``<prefix>-prepare``: take a pair (:data:`Take`), load both images (decode) and remap them to
   the rectified pair, one camera per thread (:meth:`DepthPipeline.rectify_camera`);
2. ``<prefix>-match``: the stereo matcher (:meth:`DepthPipeline.match`);
3. ``<prefix>-worker``: speckles, refinement, filters, depth (:meth:`DepthPipeline.postprocess`), in the
   order the pairs were taken (the temporal filter's history), then the sink on this thread
   (the service publishes into its result store: a reference swap), or
4. ``<prefix>-write`` with ``deliver_thread=True``: the sink on a fourth thread (files and MCAP
   messages are encoded and written while the next pair is post-processed).

Each frame's ``timings_ms`` follow one convention whoever runs it (:class:`~rig.pipeline.DepthFrame`):
processing time per stage, the two cameras' decode and remap times summed.

Stages hand over through one-item slots: at most one pair waits between two stages, and pairs
leave in the order they were taken. How pairs are taken is the caller's:

* **just in time** (:class:`JustInTime`, the service): the prepare stage takes a pair only when the
  match stage is expected to be free by the time the pair is remapped, so a slow pipeline leaves
  older pairs to the capture (which keeps the newest) instead of holding a stale one;
* **in order** (no pacing: a recording's pairs, :mod:`rig.recording_depth`): the next pair as
  soon as the match slot has room; the source reads ahead on its own thread.

A pair that fails in any stage is reported to ``on_error(key, err)`` and the stages go on; a
source that returns :data:`END` ends the run once every pair before it is delivered.

A job may name its own pipeline (:attr:`PairJob.pipeline`): a rig of N cameras hands in the pairs
of each frame set one after the other, each through its pair's pipeline
(:mod:`rig.rig_depth`), on the same stages and in the same order.
"""

from __future__ import annotations

import enum
import functools
import logging
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, Generic, Literal, TypeVar

from numpy.typing import NDArray

from rig.errors import RigError
from rig.pipeline import DepthFrame, DepthPipeline, MatchedImages, PairGeometry, RectifiedImages
from rig.priority import apply_to_current_thread

__all__ = [
    "END",
    "Ema",
    "EndOfPairs",
    "JustInTime",
    "OnError",
    "PairJob",
    "Sink",
    "Slot",
    "StagedExecutor",
    "Take",
]

log = logging.getLogger(__name__)

T = TypeVar("T")
K = TypeVar("K")

# Weight of the newest sample in the stage-time averages that time the just-in-time take.
_EMA_ALPHA = 0.2
# Start the prepare stage this much earlier than "just in time" (fraction of its time, + s).
_PREPARE_SLACK = 0.25
_PREPARE_SLACK_S = 0.0005


class _Marker(enum.Enum):
    END = "end"


EndOfPairs = Literal[_Marker.END]
END: EndOfPairs = _Marker.END
"""What a :data:`Take` returns when its source has no more pairs."""


@dataclass(frozen=True)
class PairJob(Generic[K]):
    """One pair to process: the caller's ``key`` (a frame pair, a recording's row), the left
    frame's ``seq`` and ``ts_ns``, and a loader per camera returning its image (uint8 gray or BGR,
    decoded now; it raises for a frame that cannot be read or decoded); ``pipeline``: the pair's
    own (None: the executor's)."""

    key: K
    seq: int
    ts_ns: int
    left: Callable[[], NDArray[Any]]
    right: Callable[[], NDArray[Any]]
    pipeline: DepthPipeline | None = None


Take = Callable[[float], "PairJob[Any] | EndOfPairs | None"]
"""``take(timeout_s)``: the next pair, None when none came within the timeout, or :data:`END`."""
Sink = Callable[[Any, DepthFrame], None]
"""``sink(key, frame)``: where finished pairs go, one at a time in the order they were taken,
with their stage times in ``frame.timings_ms`` (decode included; the convention is
:class:`~rig.pipeline.DepthFrame`'s). The service's result store (``DepthWorker`` publishes),
an output directory (:meth:`rig.outputs.OutputLayout.sink`) and an MCAP file
(:class:`rig.ros.mcap_export.McapDepthSink`) are the sinks of this one executor."""
OnError = Callable[[Any, BaseException], None]
"""``on_error(key, err)``: a pair failed (``key`` None: the failure was the source's)."""


class Slot(Generic[T]):
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
        ``start_at_ns()`` (re-read whenever the slot changes), or the stages stop."""
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


class Ema:
    """Exponential moving average of a duration in ns (0 before the first sample)."""

    def __init__(self) -> None:
        self.value_ns = 0.0

    def add(self, ns: float) -> None:
        self.value_ns = ns if self.value_ns == 0.0 else self.value_ns + _EMA_ALPHA * (ns - self.value_ns)


class JustInTime:
    """When the prepare stage should take the next pair: the match stage is expected free at
    ``match_free_ns``, and a pair taken now is ready after the prepare stage's usual time (plus
    some slack). Updated by the stages; read under the match slot's lock."""

    def __init__(self) -> None:
        self.prepare_time = Ema()
        self.match_cycle = Ema()
        self.match_free_ns = 0

    def start_at_ns(self) -> float:
        lead = self.prepare_time.value_ns * (1.0 + _PREPARE_SLACK) + _PREPARE_SLACK_S * 1e9
        return self.match_free_ns - lead

    def match_taken(self, now_ns: int) -> None:
        self.match_free_ns = round(now_ns + self.match_cycle.value_ns)

    def match_done(self, done_ns: int) -> None:
        """Earlier than predicted: the prepare stage may start now."""
        self.match_free_ns = min(self.match_free_ns, done_ns)


@dataclass
class _Prepared(Generic[K]):
    job: PairJob[K]
    rect: RectifiedImages
    decode_ms: float


@dataclass
class _Matched(Generic[K]):
    job: PairJob[K]
    matched: MatchedImages
    decode_ms: float


@dataclass
class _Finished(Generic[K]):
    job: PairJob[K]
    frame: DepthFrame


_Item = Any  # a stage's item or END
_Rectified = tuple[NDArray[Any], NDArray[Any], float, float]  # VPC image, gray, decode ms, remap ms


class StagedExecutor:
    """Runs ``pipeline`` on the pairs ``take`` hands in (see the module doc). ``take`` is read
    through :attr:`take` on every call, so a caller may swap it (a benchmark's gate).
    ``temporal_prior``: the pairs are one live stream, and the matcher may start from what it
    found in the rows that did not change (:meth:`DepthPipeline.match`; the service's worker)."""

    def __init__(
        self,
        pipeline: DepthPipeline,
        take: Take,
        sink: Sink,
        *,
        on_error: OnError,
        pacing: JustInTime | None = None,
        deliver_thread: bool = False,
        poll_s: float = 0.1,
        prefix: str = "rig-depth",
        temporal_prior: bool = False,
    ) -> None:
        self.pipeline = pipeline
        self._temporal_prior = temporal_prior
        self.take = take
        self._sink = sink
        self._on_error = on_error
        self._pacing = pacing
        self._poll_s = poll_s
        self._prefix = prefix
        self._stop = threading.Event()
        self._ended = threading.Event()
        self._threads: list[threading.Thread] = []
        self._decoder: ThreadPoolExecutor | None = None
        self._to_match: Slot[_Item] = Slot(self._stop, poll_s)
        self._to_postprocess: Slot[_Item] = Slot(self._stop, poll_s)
        self._to_deliver: Slot[_Item] | None = Slot(self._stop, poll_s) if deliver_thread else None

    # ----- lifecycle ---------------------------------------------------------------------------
    def start(self) -> None:
        if self._threads:
            return
        self._decoder = ThreadPoolExecutor(
            max_workers=1, thread_name_prefix=f"{self._prefix}-decode", initializer=apply_to_current_thread
        )
        stages: list[tuple[str, Callable[[], bool]]] = [
            ("prepare", self._prepare_step),
            ("match", self._match_step),
            ("worker", self._postprocess_step),
        ]
        if self._to_deliver is not None:
            stages.append(("write", self._deliver_step))
        for name, step in stages:
            thread = threading.Thread(
                target=self._guarded, args=(step,), name=f"{self._prefix}-{name}", daemon=True
            )
            self._threads.append(thread)
        for thread in self._threads:
            thread.start()

    def wait(self, timeout_s: float | None = None) -> bool:
        """Wait until the source's :data:`END` has passed every stage (True) or the timeout."""
        return self._ended.wait(timeout_s)

    @property
    def ended(self) -> bool:
        return self._ended.is_set()

    def stop(self, timeout_s: float = 10.0) -> None:
        self._stop.set()
        for slot in (self._to_match, self._to_postprocess, self._to_deliver):
            if slot is not None:
                slot.notify()
        deadline = time.monotonic() + timeout_s
        for thread in self._threads:
            if thread is not threading.current_thread():
                thread.join(max(0.0, deadline - time.monotonic()))
        if self._decoder is not None:
            self._decoder.shutdown(wait=False, cancel_futures=True)

    def is_alive(self) -> bool:
        return bool(self._threads) and all(t.is_alive() for t in self._threads)

    # ----- stages ------------------------------------------------------------------------------
    def _guarded(self, step: Callable[[], bool]) -> None:
        """Run one stage's step until it has passed :data:`END` on or the stages stop. A pair's
        failure is reported by the step; anything else (the source's) here, and never fatal."""
        apply_to_current_thread()
        while not self._stop.is_set():
            try:
                if not step():
                    return
            except Exception as err:
                self._on_error(None, err)
                if not isinstance(err, RigError):
                    self._stop.wait(self._poll_s)  # a bug: do not spin on it

    def _prepare_step(self) -> bool:
        pacing = self._pacing
        if pacing is not None:
            self._to_match.wait_empty(pacing.start_at_ns)
            if self._stop.is_set():
                return False
        job = self.take(self._poll_s)
        if job is None:
            return True
        if job is END:
            self._to_match.put(END)
            return False
        t0 = time.perf_counter_ns()
        try:
            rect, decode_ms = self._rectify(job)
        except Exception as err:
            self._on_error(job.key, err)
            return True
        if pacing is not None:
            pacing.prepare_time.add(time.perf_counter_ns() - t0)
        self._to_match.put(_Prepared(job, rect, decode_ms))
        return True

    def pipeline_of(self, job: PairJob[Any]) -> DepthPipeline:
        """The pipeline ``job`` runs through: its own, or the executor's."""
        return job.pipeline or self.pipeline

    def _rectify(self, job: PairJob[Any]) -> tuple[RectifiedImages, float]:
        """Load and remap one pair, the two cameras on two threads: JPEG decoding is
        single-threaded, and two remaps at once beat one parallelised after another."""
        pipeline = self.pipeline_of(job)
        left_name, right_name = pipeline.names
        # One geometry for both frames: a corrected calibration swapped in meanwhile
        # (DepthPipeline.apply) starts with the next pair.
        geometry = pipeline.geometry
        decoder = self._decoder
        load = functools.partial(self._load_rectify, pipeline)
        if decoder is None:
            left = load(left_name, job.left, geometry)
            right = load(right_name, job.right, geometry)
        else:
            future: Future[_Rectified] = decoder.submit(load, left_name, job.left, geometry)
            try:
                right = load(right_name, job.right, geometry)
            finally:
                left = future.result()  # also when the right failed: no thread left on this pair
        right_rect, right_gray, right_decode, right_remap = right
        left_rect, left_gray, left_decode, left_remap = left
        # Processing time, summed over the cameras however they ran (DepthFrame's convention).
        rect = RectifiedImages(
            left_rect, right_rect, left_gray, right_gray, left_remap + right_remap, geometry
        )
        return rect, left_decode + right_decode

    @staticmethod
    def _load_rectify(
        pipeline: DepthPipeline, name: str, load: Callable[[], NDArray[Any]], geometry: PairGeometry
    ) -> _Rectified:
        t0 = time.perf_counter()
        image = load()
        t1 = time.perf_counter()
        vpc, gray = pipeline.rectify_camera(name, image, geometry)
        t2 = time.perf_counter()
        return vpc, gray, (t1 - t0) * 1e3, (t2 - t1) * 1e3

    def _match_step(self) -> bool:
        pacing = self._pacing
        t0 = 0

        def taken() -> None:  # under the slot's lock: the prepare stage sees it when it wakes
            nonlocal t0
            t0 = time.monotonic_ns()
            if pacing is not None:
                pacing.match_taken(t0)

        item = self._to_match.take(taken)
        if item is None:
            return True
        if item is END:
            self._to_postprocess.put(END)
            return False
        try:
            # Each pair's matcher keeps its own stream's prior (a ring: one per pair).
            matched = self.pipeline_of(item.job).match(item.rect, temporal_prior=self._temporal_prior)
        except Exception as err:
            self._on_error(item.job.key, err)
            matched = None
        try:
            if matched is not None:
                self._to_postprocess.put(_Matched(item.job, matched, item.decode_ms))
        finally:
            if pacing is not None:
                # The cycle includes any wait for the post-processing stage: that is when it is free again.
                done = time.monotonic_ns()
                pacing.match_cycle.add(done - t0)
                self._to_match.update(lambda: pacing.match_done(done))
        return True

    def _postprocess_step(self) -> bool:
        item = self._to_postprocess.take()
        if item is None:
            return True
        if item is END:
            if self._to_deliver is not None:
                self._to_deliver.put(END)
            else:
                self._ended.set()
            return False
        job = item.job
        try:
            frame = self.pipeline_of(job).postprocess(item.matched, job.seq, job.ts_ns)
        except Exception as err:
            self._on_error(job.key, err)
            return True
        timings = {"decode": item.decode_ms, **frame.timings_ms}
        timings["total"] = frame.timings_ms.get("total", 0.0) + item.decode_ms
        frame.timings_ms = timings
        if self._to_deliver is not None:
            self._to_deliver.put(_Finished(job, frame))
        else:
            self._deliver_one(job, frame)
        return True

    def _deliver_step(self) -> bool:
        assert self._to_deliver is not None
        item = self._to_deliver.take()
        if item is None:
            return True
        if item is END:
            self._ended.set()
            return False
        self._deliver_one(item.job, item.frame)
        return True

    def _deliver_one(self, job: PairJob[Any], frame: DepthFrame) -> None:
        try:
            self._sink(job.key, frame)
        except Exception as err:
            self._on_error(job.key, err)
