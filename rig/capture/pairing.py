"""Stereo pairing by nearest capture timestamps, with a skew gate.

Each camera's frames wait in a bounded buffer (oldest dropped when full). Pairing looks only at
the two buffer heads, so the result depends on the two timestamp streams and not on which
thread delivered first:

- heads more than ``gate`` apart: the older head can never be paired (every later frame of the
  other camera is later still) and is dropped as *unpaired*;
- within the gate: paired, unless the next buffered frame of the other camera is closer (only
  possible with a gate above half a frame period);

so a frame whose partner was lost is dropped and counted, and nothing pairs across a gap.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from rig.capture.frame import Frame, FramePair

__all__ = ["FramePairer", "PairerCounts"]


@dataclass(frozen=True)
class PairerCounts:
    """Per camera: frames dropped for lack of a partner / pushed out of a full buffer."""

    unpaired: dict[str, int]
    evicted: dict[str, int]
    buffered: dict[str, int]
    pairs_formed: int


class FramePairer:
    """Pairs frames of two cameras (see module docstring). Not thread-safe: callers lock."""

    def __init__(
        self,
        gate_ns: int,
        buffer_size: int = 8,
        skew_window: int = 300,
        names: Sequence[str] = ("left", "right"),
    ) -> None:
        if gate_ns <= 0:
            raise ValueError("gate_ns must be > 0")
        if len(names) != 2:
            raise ValueError("pairing needs exactly two cameras")
        self.gate_ns = int(gate_ns)
        self.buffer_size = int(buffer_size)
        self.left_name, self.right_name = names
        self._buf: dict[str, deque[Frame]] = {n: deque() for n in names}
        self._unpaired = dict.fromkeys(names, 0)
        self._evicted = dict.fromkeys(names, 0)
        self._ended: set[str] = set()
        self._skews: deque[int] = deque(maxlen=skew_window)
        self.pairs_formed = 0

    def buffered(self, camera: str) -> int:
        return len(self._buf[camera])

    def push(self, frame: Frame) -> list[FramePair]:
        """Add one frame; returns the pairs it completed (in time order)."""
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
        """No further pair is possible: a camera has ended and nothing of it is left to pair."""
        both = {self.left_name, self.right_name} <= self._ended
        return both or any(not self._buf[c] for c in self._ended)

    def drop_buffered(self) -> None:
        """Discard everything waiting (counted as unpaired), e.g. when capture stops."""
        for name, buf in self._buf.items():
            self._unpaired[name] += len(buf)
            buf.clear()

    def _drop(self, name: str) -> None:
        self._buf[name].popleft()
        self._unpaired[name] += 1

    def _match(self) -> list[FramePair]:
        left, right = self._buf[self.left_name], self._buf[self.right_name]
        gate = self.gate_ns
        out: list[FramePair] = []
        while left and right:
            lf, rf = left[0], right[0]
            d = lf.ts_ns - rf.ts_ns
            if d < -gate:
                self._drop(self.left_name)
            elif d > gate:
                self._drop(self.right_name)
            elif len(left) > 1 and abs(left[1].ts_ns - rf.ts_ns) < abs(d):
                self._drop(self.left_name)
            elif len(right) > 1 and abs(right[1].ts_ns - lf.ts_ns) < abs(d):
                self._drop(self.right_name)
            else:
                left.popleft()
                right.popleft()
                self._skews.append(abs(d))
                self.pairs_formed += 1
                out.append(FramePair(lf, rf))
        return out

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
