"""Synchronised sets by nearest capture timestamps, with a skew gate: pairs of two cameras, and
sets of N.

Each camera's frames wait in a bounded buffer (oldest dropped when full). Pairing looks only at
the buffer heads, so the result depends on the timestamp streams and not on which thread
delivered first:

- heads spread over more than ``gate`` (latest minus earliest): the oldest head can never be in a
  set (every later frame of the camera whose head is latest is later still) and is dropped as
  *unpaired*;
- within the gate: a set, unless some camera's next buffered frame would make the spread
  smaller (only possible with a gate above half a frame period): then that camera's head is
  dropped (cameras in order, the first such one);

so a frame whose partner was lost is dropped and counted, and nothing pairs across a gap. With
two cameras these are exactly a pair's rules (heads more than ``gate`` apart; the other camera's
next frame closer), and the sets are :class:`~rig.capture.frame.FramePair`.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from rig.capture.frame import Frame, FramePair, FrameSet

__all__ = ["FramePairer", "PairerCounts"]


@dataclass(frozen=True)
class PairerCounts:
    """Per camera: frames dropped for lack of a partner / pushed out of a full buffer."""

    unpaired: dict[str, int]
    evicted: dict[str, int]
    buffered: dict[str, int]
    pairs_formed: int


class FramePairer:
    """Sets of frames of ``names`` (two or more cameras; see module docstring). Not thread-safe:
    callers lock."""

    def __init__(
        self,
        gate_ns: int,
        buffer_size: int = 8,
        skew_window: int = 300,
        names: Sequence[str] = ("left", "right"),
    ) -> None:
        if gate_ns <= 0:
            raise ValueError("gate_ns must be > 0")
        if len(names) < 2 or len(set(names)) != len(names):
            raise ValueError(f"pairing needs two or more different cameras, got {list(names)}")
        self.gate_ns = int(gate_ns)
        self.buffer_size = int(buffer_size)
        self.names = list(names)
        self._buf: dict[str, deque[Frame]] = {n: deque() for n in names}
        self._unpaired = dict.fromkeys(names, 0)
        self._evicted = dict.fromkeys(names, 0)
        self._ended: set[str] = set()
        self._skews: deque[int] = deque(maxlen=skew_window)
        self.pairs_formed = 0

    def buffered(self, camera: str) -> int:
        return len(self._buf[camera])

    def push(self, frame: Frame) -> list[FrameSet]:
        """Add one frame; returns the sets it completed (in time order; :class:`FramePair` for
        two cameras)."""
        buf = self._buf[frame.camera]
        if len(buf) >= self.buffer_size:
            buf.popleft()
            self._evicted[frame.camera] += 1
        buf.append(frame)
        return self._match()

    def end(self, camera: str) -> None:
        """The camera will deliver no more frames (end of a replay)."""
        self._ended.add(camera)

    @property
    def exhausted(self) -> bool:
        """No further set is possible: a camera has ended and nothing of it is left to pair."""
        every = set(self.names) <= self._ended
        return every or any(not self._buf[c] for c in self._ended)

    def drop_buffered(self) -> None:
        """Discard everything waiting (counted as unpaired), e.g. when capture stops."""
        for name, buf in self._buf.items():
            self._unpaired[name] += len(buf)
            buf.clear()

    def _drop(self, name: str) -> None:
        self._buf[name].popleft()
        self._unpaired[name] += 1

    def _match(self) -> list[FrameSet]:
        bufs = [self._buf[n] for n in self.names]
        gate = self.gate_ns
        out: list[FrameSet] = []
        while all(bufs):
            stamps = [b[0].ts_ns for b in bufs]
            lo, hi = min(stamps), max(stamps)
            if hi - lo > gate:
                self._drop(self.names[stamps.index(lo)])
                continue
            closer = self._closer_next(bufs, stamps, hi - lo)
            if closer is not None:
                self._drop(self.names[closer])
                continue
            frames = tuple(b.popleft() for b in bufs)
            self._skews.append(hi - lo)
            self.pairs_formed += 1
            out.append(FramePair(*frames) if len(frames) == 2 else FrameSet(frames))
        return out

    @staticmethod
    def _closer_next(bufs: list[deque[Frame]], stamps: list[int], spread: int) -> int | None:
        """The first camera whose next buffered frame would make the heads' spread smaller."""
        for k, buf in enumerate(bufs):
            if len(buf) > 1:
                others = stamps[:k] + stamps[k + 1 :]
                t = buf[1].ts_ns
                if max(*others, t) - min(*others, t) < spread:
                    return k
        return None

    def counts(self) -> PairerCounts:
        return PairerCounts(
            unpaired=dict(self._unpaired),
            evicted=dict(self._evicted),
            buffered={n: len(b) for n, b in self._buf.items()},
            pairs_formed=self.pairs_formed,
        )

    def skew_percentiles_ms(self) -> tuple[float | None, float | None]:
        """p50 and p95 of |skew| over the last ``skew_window`` pairs, in ms (None before any pair)."""
        if not self._skews:
            return None, None
        p50, p95 = np.percentile(np.fromiter(self._skews, dtype=np.float64), [50.0, 95.0]) / 1e6
        return float(p50), float(p95)

    @property
    def skew_samples(self) -> int:
        return len(self._skews)
