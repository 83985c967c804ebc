"""A camera that replays one camera of a recording directory (docs/cameras.md) or of a ROS bag
(:mod:`rig.capture.recorded`), with fault injection.

It goes through the same protocol, supervisor and pairing as a V4L2 camera. Timing:

- ``pace="recorded"``: frame k is due at ``anchor + (ts_k - ts_0)`` (one loop later: plus the
  recording's span); ``pace=<fps>``: at ``anchor + k / fps``; ``pace="fast"``: at once.
- ``timestamps="recorded"`` delivers the recording's ``seq`` and ``ts_ns`` verbatim (a re-record
  is byte-identical); ``"live"`` delivers the due time as ``ts_ns`` (CLOCK_MONOTONIC, so frame age
  means something) and a ``seq`` that keeps increasing across loops.
- The anchor comes from a :class:`~rig.capture.protocol.TimeBase`; two cameras replaying the
  same recording through one TimeBase share a clock, so their pairs line up exactly.
- A paced camera never delivers frames due during a stall or disconnect, nor frames due more than
  ``CATCH_UP_S`` before it is read (after a reopen, or when the reading thread was starved of CPU):
  like a real camera whose driver ring buffer overran, it loses them (gaps in ``seq``). So a
  delivered frame is never older than ``CATCH_UP_S``, well inside the supervisor's clock check.
"""

from __future__ import annotations

import itertools
import statistics
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from typing import Any

from rig.capture.config import FileCameraConfig
from rig.capture.faults import Fault, FaultPlan, parse_fault
from rig.capture.frame import Frame, FrameFormat
from rig.capture.protocol import CameraInfo, TimeBase
from rig.capture.recorded import open_recording
from rig.errors import CameraUnavailable, ConfigError, CorruptFrameError, EndOfStream, RecordingError

__all__ = ["FileCamera", "FileCameraStats"]

_DEFAULT_PERIOD_NS = 33_333_333


@dataclass(frozen=True)
class FileCameraStats:
    """What the camera itself did, for cross-checking the supervisor's counters exactly.

    ``lost``: recorded frames skipped after the first delivered one (stall/disconnect windows,
    ``rate``/``drop`` faults, catch-up) — each shows up as a ``seq`` gap.
    ``lost_late``: the part of ``lost`` skipped by catch-up (due more than ``CATCH_UP_S`` before
    the read: a reopen after backoff, a starved reader); ``lost - lost_late`` is what faults cost.
    ``skipped_at_start``: frames skipped before the first delivery (no gap anyone can see).
    """

    delivered: int = 0
    lost: int = 0
    lost_late: int = 0
    skipped_at_start: int = 0
    corrupted: int = 0
    truncated: int = 0
    unreadable: int = 0
    opens: int = 0
    disconnects: int = 0
    resets: int = 0


class FileCamera:
    """Replays ``config.camera`` (default: ``name``) of ``config.recording``; see module docstring."""

    kind = "file"
    CATCH_UP_S = 0.25

    def __init__(
        self,
        config: FileCameraConfig,
        name: str,
        *,
        timebase: TimeBase | None = None,
        clock: Callable[[], int] = time.monotonic_ns,
    ) -> None:
        self.name = name
        self.config = config
        self._clock = clock
        self._timebase = timebase or TimeBase(clock)
        self._cam = config.camera or name
        rec = open_recording(
            config.recording,
            left_topic=config.left_topic,
            right_topic=config.right_topic,
            max_skew_ms=config.max_skew_ms,
            topics=config.topics,
        )
        if self._cam not in rec.cameras:
            raise ConfigError(f"{rec.root}: recording has no camera {self._cam!r} (has {rec.cameras})")
        if not rec.pairs:
            raise RecordingError(f"{rec.root}: recording holds no frames")
        self._rec = rec
        pairs = rec.pairs
        self._seqs = [p.seq for p in pairs]
        self._ts = [p.ts_ns(self._cam) for p in pairs]
        # One reference for every camera of the recording keeps their relative skew when rebased.
        self._ref_ns = min(pairs[0].stamps)
        diffs = [b.first_ts_ns - a.first_ts_ns for a, b in itertools.pairwise(pairs)]
        positive = [d for d in diffs if d > 0]
        self._rec_period_ns = int(statistics.median(positive)) if positive else _DEFAULT_PERIOD_NS
        # One loop lasts the first camera's span plus a period, the same for every camera.
        self._span_ns = pairs[-1].first_ts_ns - pairs[0].first_ts_ns + self._rec_period_ns
        self._seq_span = self._seqs[-1] - self._seqs[0] + 1
        pace = config.pace
        self._period_ns = round(1e9 / pace) if isinstance(pace, float) else self._rec_period_ns
        self._format, self._size = self._probe()

        self._cond = threading.Condition()
        self._plan = FaultPlan(list(config.faults))
        self._open = False
        self._anchor_ns: int | None = None
        self._first_open_ns: int | None = None
        self._pos = 0
        self._stats = FileCameraStats()

    # ----- protocol ----------------------------------------------------------------------------
    @property
    def nominal_fps(self) -> float:
        return 1e9 / self._period_ns

    def info(self) -> CameraInfo:
        return CameraInfo(
            name=self.name,
            kind=self.kind,
            device=f"{self._rec.root}:{self._cam}",
            format=self._format,
            width=self._size[0],
            height=self._size[1],
            fps=self.nominal_fps,
            timestamp_source=self.config.timestamps,
            timestamp_note=None,
        )

    def open(self) -> None:
        with self._cond:
            now = self._clock()
            self._fire_due(now)
            if self._plan.disconnected(now):
                raise CameraUnavailable(f"camera {self.name}: {self._device()} disconnected (injected fault)")
            if self._anchor_ns is None:
                self._anchor_ns = self._timebase.anchor_ns()
                self._first_open_ns = now
            self._plan.reset_clock()
            self._open = True
            self._stats = replace(self._stats, opens=self._stats.opens + 1)

    def close(self) -> None:
        with self._cond:
            self._open = False
            self._cond.notify_all()

    def read(self, timeout_s: float) -> Frame | None:
        deadline = self._clock() + round(timeout_s * 1e9)
        with self._cond:
            while True:
                if not self._open:
                    raise CameraUnavailable(f"camera {self.name}: not open")
                now = self._clock()
                k = self._pos
                if not self.config.loop and k >= len(self._seqs):
                    raise EndOfStream(f"camera {self.name}: end of recording {self._rec.root}")
                due = self._due_ns(k)
                # Scheduled faults take effect at the next frame's due time: same frames lost every run.
                self._fire_due(now if due is None else due)
                if self._plan.disconnected(now):
                    self._open = False
                    self._stats = replace(self._stats, disconnects=self._stats.disconnects + 1)
                    raise CameraUnavailable(
                        f"camera {self.name}: {self._device()} disconnected (injected fault)"
                    )
                wait_until = self._plan.stall_until_ns if self._plan.stalled(now) else None
                if wait_until is None and due is not None:
                    if self._lost_to_outage(due):
                        self._skip()
                        continue
                    if due < now - round(self.CATCH_UP_S * 1e9):
                        # Delivering it would hand out a stale frame the supervisor rejects as
                        # a clock jump (and reconnects): catch up instead, as a real camera would.
                        self._skip(late=True)
                        continue
                    if due > now:
                        wait_until = due
                if wait_until is not None:
                    if now >= deadline:
                        return None
                    self._cond.wait((min(wait_until, deadline) - now) / 1e9)
                    continue
                if self._plan.lose_next(due if due is not None else now):
                    self._skip()
                    continue
                return self._deliver(k, due, now)

    def reset_hardware(self) -> str:
        with self._cond:
            self._stats = replace(self._stats, resets=self._stats.resets + 1)
        return f"camera {self.name}: file camera, nothing to reset (re-opened instead)"

    # ----- faults ------------------------------------------------------------------------------
    def inject(self, fault: Fault | Mapping[str, Any]) -> None:
        """Activate a fault before the next frame; thread-safe (see rig.capture.faults)."""
        f = parse_fault(fault) if isinstance(fault, Mapping) else fault
        with self._cond:
            now = self._clock()
            due = self._due_ns(self._pos) if self._open else None
            # A stall/disconnect starts at the due time of the next frame not yet delivered, so
            # that frame is lost too and a window of D seconds loses ceil(D·fps) frames whether or
            # not the reading thread is running late (a frame due long ago is skipped anyway).
            late = due is not None and due < now - round(self.CATCH_UP_S * 1e9)
            self._plan.inject(f, now if due is None or late else due)
            self._cond.notify_all()

    def stats(self) -> FileCameraStats:
        with self._cond:
            return self._stats

    # ----- internals ---------------------------------------------------------------------------
    @property
    def _paced(self) -> bool:
        return self.config.pace != "fast"

    def _device(self) -> str:
        return f"{self._rec.root} ({self._cam})"

    def _due_ns(self, k: int) -> int | None:
        if not self._paced or self._anchor_ns is None:
            return None
        n = len(self._seqs)
        if isinstance(self.config.pace, float):
            return self._anchor_ns + k * self._period_ns
        loops, i = divmod(k, n)
        return self._anchor_ns + (self._ts[i] - self._ref_ns) + loops * self._span_ns

    def _fire_due(self, effective_ns: int) -> None:
        elapsed = None
        if self._first_open_ns is not None:
            elapsed = (self._clock() - self._first_open_ns) / 1e9
        if self._plan.fire_due(self._stats.delivered, elapsed, effective_ns):
            self._cond.notify_all()

    def _lost_to_outage(self, due: int) -> bool:
        end = self._plan.outage_end_ns()
        return end is not None and due < end

    def _skip(self, *, late: bool = False) -> None:
        self._pos += 1
        s = self._stats
        if s.delivered:
            self._stats = replace(s, lost=s.lost + 1, lost_late=s.lost_late + late)
        else:
            self._stats = replace(s, skipped_at_start=s.skipped_at_start + 1)

    def _deliver(self, k: int, due: int | None, now: int) -> Frame:
        n = len(self._seqs)
        loops, i = divmod(k, n)
        self._pos += 1
        if self.config.timestamps == "live" and due is not None:
            seq, ts = self._seqs[i] + loops * self._seq_span, due
        else:
            seq, ts = self._seqs[i], self._ts[i]
        ts += self._plan.jump_offset_ns
        s = self._stats
        self._stats = replace(s, delivered=s.delivered + 1)
        try:
            # The index may name anything: the recording refuses paths leaving it and names
            # the file in its message.
            stored = self._rec.read_frame(self._rec.pairs[i], self._cam)
        except (RecordingError, CorruptFrameError) as err:
            self._stats = replace(self._stats, unreadable=self._stats.unreadable + 1)
            raise CorruptFrameError(f"camera {self.name}: frame {seq}: {err}") from err
        if stored.raw is None:  # a bag's raw pixels: nothing encoded to corrupt
            assert stored.image is not None
            return Frame.from_image(self.name, seq, ts, stored.image, self._clock(), stored.source)
        data, mangled = self._plan.mangle(stored.raw)
        if mangled == "corrupt":
            self._stats = replace(self._stats, corrupted=self._stats.corrupted + 1)
        elif mangled == "truncate":
            self._stats = replace(self._stats, truncated=self._stats.truncated + 1)
        fmt: FrameFormat = "png" if stored.format == "png" else "jpeg"
        expected = self._size if all(self._size) else None
        return Frame(
            self.name, seq, ts, fmt, self._clock(), raw=data, source=stored.source, expected_size=expected
        )

    def _probe(self) -> tuple[str, tuple[int, int]]:
        """The first frame's format and the size its header declares, read without decoding it
        ((0, 0) when it cannot be read)."""
        try:
            stored = self._rec.read_frame(self._rec.pairs[0], self._cam)
        except RecordingError:
            return "unknown", (0, 0)
        try:
            return stored.format, stored.declared_size()
        except RecordingError:
            return stored.format, (0, 0)
