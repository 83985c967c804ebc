"""The depth worker: takes the newest pair from the capture, runs the pipeline and publishes the
result, on the staged executor of :mod:`rig.staged` (the one executor ``rig process`` and ``rig
export mcap`` run too; the stages on three threads, so that consecutive frames overlap on a
multi-core CPU), with the result store as its sink:

1. ``rig-depth-prepare``: take the newest pair, decode both frames' luma (unless the capture did)
   and remap them to the rectified pair, one frame per thread;
2. ``rig-depth-match``: the stereo matcher;
3. ``rig-depth-worker``: refinement, filters, depth and publishing.

Frames stay fresh: the prepare stage takes a pair from the capture only *just in time* — when
the match stage is expected to be free by the time the pair is remapped
(:class:`rig.staged.JustInTime`) — so a slow pipeline drops older pairs in the capture (counted
there as skipped) instead of holding a stale one. Publishing is a reference swap; clients
encode what they need from the published result in their own threads. A failing frame is
counted and reported, and the worker goes on: one that does not decode against its camera
(``frames_undecodable``), any other failure (a wrong size, say) as the worker's error.

A rig of N cameras (``ring``): the worker takes the newest synchronised set and hands the executor
its pairs one after the other, each through its pair's pipeline; when the last pair of a set is
finished the set is published (``frame``/``left``/``right`` its first pair's, every pair in
:class:`~service.store.RingResult`, the panorama fused when first asked for). A set one of whose
pairs fails is counted once and not published.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Protocol

from numpy.typing import NDArray

from rig.capture.frame import Frame, FramePair, FrameSet
from rig.counters import Counts, Tally, complete
from rig.errors import CorruptFrameError, RigError
from rig.pipeline import DepthFrame, DepthPipeline
from rig.rig_depth import SetCollector
from rig.rig_pipeline import RigPipeline
from rig.staged import EndOfPairs, JustInTime, PairJob, StagedExecutor
from service.store import PublishedResult, ResultStore, RingResult

__all__ = ["DepthWorker", "PairSource", "WorkerStats", "render_rectified"]

log = logging.getLogger("service.worker")

STAGES = ("decode", "remap", "match", "refine", "filters", "depth", "total")


class PairSource(Protocol):
    def next_pair(self, timeout_s: float, *, newest: bool = True) -> FramePair | None: ...

    def next_set(self, timeout_s: float, *, newest: bool = True) -> FrameSet | None: ...

    def report_undecodable(self, frame: Frame, err: Exception) -> None:
        """A frame of a pair taken from this source did not decode (the camera's fault)."""


@dataclass(frozen=True, eq=False)
class _Part:
    """One pair of a rig's set: the executor's key of its job."""

    set: FrameSet
    label: str


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


def render_rectified(pipeline: DepthPipeline, camera: str, frame: Frame) -> NDArray[Any]:
    """The VPC image of ``camera`` (``left``/``right``) from its raw ``frame``'s full (colour)
    image: what :meth:`PublishedResult.rect_image` asks for."""
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
        on_pair: Callable[[FrameSet], None] | None = None,
        on_result: Callable[[PublishedResult, dict[str, float]], None] | None = None,
        poll_s: float = 0.1,
        window_s: float = 2.0,
        prefetch: Mapping[str, Callable[[PublishedResult], bytes]] | None = None,
        ring: RigPipeline | None = None,
    ) -> None:
        self.source = source
        self.pipeline = pipeline
        self.ring = ring
        self._pending: deque[PairJob[_Part]] = deque()  # a set's pairs not yet taken
        self._sets: SetCollector[FrameSet] = SetCollector(len(ring.pipelines) if ring else 1)
        self.store = store
        self._on_pair = on_pair
        self._on_result = on_result
        self._poll_s = poll_s
        self._window_ns = round(window_s * 1e9)
        self._lock = threading.Lock()
        self._recent: deque[tuple[int, dict[str, float], float]] = deque(maxlen=256)
        self._counters = Tally("worker")  # under self._lock
        self._last_error: tuple[str, int] | None = None
        self._last_seq: int | None = None
        self._last_published_ns: int | None = None
        self._prefetch = dict(prefetch or {})
        self._previous: PublishedResult | None = None
        self._stages = StagedExecutor(
            pipeline,
            self._take,
            self._publish,
            on_error=self._on_error,
            pacing=JustInTime(),
            poll_s=poll_s,
            prefix="rig-depth",
            temporal_prior=True,  # a live stream in order: stereo.temporal_prior may use it
        )

    # ----- lifecycle ---------------------------------------------------------------------------
    def start(self) -> None:
        self._stages.start()

    def stop(self, timeout_s: float = 10.0) -> None:
        self._stages.stop(timeout_s)

    def is_alive(self) -> bool:
        return self._stages.is_alive()

    # ----- the stages' source and sinks --------------------------------------------------------
    def _take(self, timeout_s: float) -> PairJob[Any] | EndOfPairs | None:
        """The newest pair of :attr:`source` (read on every take: a benchmark may gate it); a
        rig's: the next pair of the newest set."""
        if self.ring is not None:
            return self._take_part(self.ring, timeout_s)
        pair = self.source.next_pair(timeout_s, newest=True)
        if pair is None:
            return None
        if self._on_pair is not None:
            self._on_pair(pair)
        return PairJob(
            pair,
            pair.seq,
            pair.ts_ns,
            functools.partial(self._luma, pair.left),
            functools.partial(self._luma, pair.right),
        )

    def _take_part(self, ring: RigPipeline, timeout_s: float) -> PairJob[_Part] | None:
        if not self._pending:
            frames = self.source.next_set(timeout_s, newest=True)
            if frames is None:
                return None
            if self._on_pair is not None:
                self._on_pair(frames)
            for label, p in ring.pipelines.items():
                left, right = (frames.frame(n) for n in p.names)
                self._pending.append(
                    PairJob(
                        _Part(frames, label),
                        frames.seq,
                        frames.ts_ns,
                        functools.partial(self._luma, left),
                        functools.partial(self._luma, right),
                        pipeline=p,
                    )
                )
        return self._pending.popleft()

    def _luma(self, frame: Frame) -> NDArray[Any]:
        """The frame's luma (decoded now unless the capture thread did); a frame that does not
        decode is reported to the source, which counts it against its camera."""
        try:
            return frame.gray
        except CorruptFrameError as err:
            self.source.report_undecodable(frame, err)
            raise

    def _on_error(self, pair: FramePair | _Part | None, err: BaseException) -> None:
        if (
            isinstance(pair, _Part)
            and self._sets.resolve(pair.set.seq, pair.set, pair.label, None, err) is None
        ):
            return  # the set's other pairs are still out: the set fails once, when they are back
        if isinstance(err, CorruptFrameError):
            return  # counted against its camera (_luma); the worker itself is fine
        if isinstance(err, RigError):
            self._failed(str(err))
            return
        # A bug must not kill the service's only worker.
        log.error("depth worker: unexpected error", exc_info=err)
        self._failed(f"{type(err).__name__}: {err}")

    def _publish_part(self, part: _Part, frame: DepthFrame) -> None:
        """A rig's pair: published with its set's other pairs once they are all back."""
        assert self.ring is not None
        entry = self._sets.resolve(part.set.seq, part.set, part.label, frame, None)
        if entry is None:
            return
        if entry.error is not None:
            self._on_error(None, entry.error)
            return
        first = self.ring.first
        pairs = {label: entry.frames[label] for label in self.ring.labels}
        lead = pairs[self.ring.labels[0]]
        # The set's processing time: each stage summed over its pairs (DepthFrame's convention).
        stages = dict.fromkeys(k for f in pairs.values() for k in f.timings_ms)
        lead.timings_ms = {k: sum(f.timings_ms.get(k, 0.0) for f in pairs.values()) for k in stages}
        lead.searched = max(f.searched for f in pairs.values())  # kept: every pair's search
        frames = entry.set
        ring = RingResult(self.ring, frames, pairs)
        self._publish_frames(frames, lead, frames.frame(first.names[0]), frames.frame(first.names[1]), ring)

    def _publish(self, pair: FramePair | _Part, frame: DepthFrame) -> None:
        """The executor's sink: ``frame`` into the result store (see the module doc)."""
        if isinstance(pair, _Part):
            self._publish_part(pair, frame)
            return
        self._publish_frames(pair, frame, pair.left, pair.right, None)

    def _publish_frames(
        self, pair: FrameSet, frame: DepthFrame, left: Frame, right: Frame, ring: RingResult | None
    ) -> None:
        timings = frame.timings_ms
        arrived = max(f.host_ns for f in pair.frames)
        with self._lock:
            self._counters.add("frames_processed")
            if frame.searched == 0.0:
                self._counters.add("searches_kept")
            index = self._counters["frames_processed"]
        result = PublishedResult(
            index=index,
            frame=frame,
            left=left,
            right=right,
            published_ns=0,
            age_ms=0.0,
            cache=self.store.new_cache(),
            render_rectified=functools.partial(render_rectified, self.pipeline),
            ring=ring,
        )
        # Encode what clients polled on the previous frame *before* this one becomes visible: a
        # poll then always finds its bytes ready (no request waits on the encode, none takes a
        # thread hop), for the price of that encode's time in every client's frame age.
        self._prefetch_for(result)
        now = time.monotonic_ns()
        result = dataclasses.replace(result, published_ns=now, age_ms=(now - arrived) / 1e6)
        self._previous = result
        self.store.publish(result)
        with self._lock:
            self._recent.append((now, timings, result.age_ms))
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
            "processing_ms": stage_ms.get("total"),
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
