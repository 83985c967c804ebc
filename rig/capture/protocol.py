"""The one camera protocol every source implements (V4L2 hardware, file-backed replays).

A camera is driven by exactly one thread (its supervisor's): ``open`` → ``read`` … → ``close``.
``read`` returns a :class:`~rig.capture.frame.Frame`, or None when no frame came within the
timeout; it raises :class:`~rig.errors.CameraUnavailable` when the device is gone (the
supervisor closes and reconnects), :class:`~rig.errors.EndOfStream` at the end of a replay, and
:class:`~rig.errors.CorruptFrameError` for a frame it could not even retrieve.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal, Protocol, runtime_checkable

from rig.capture.faults import Fault
from rig.capture.frame import Frame

__all__ = ["Camera", "CameraInfo", "FaultInjectable", "TimeBase", "TimestampSource"]

TimestampSource = Literal["v4l2", "host", "recorded", "live"]
"""Where ``Frame.ts_ns`` comes from: the V4L2 buffer (CLOCK_MONOTONIC), the host clock at grab
time (fallback), a recording verbatim, or a recording rebased onto ``time.monotonic_ns()``."""


@dataclass(frozen=True)
class CameraInfo:
    """What a camera negotiated; ``timestamp_note`` says why a fallback was chosen."""

    name: str
    kind: str
    device: str
    format: str
    width: int
    height: int
    fps: float | None
    timestamp_source: TimestampSource | None = None
    timestamp_note: str | None = None

    @property
    def host_clock(self) -> bool:
        """True when timestamps are on this host's CLOCK_MONOTONIC (so they can be checked)."""
        return self.timestamp_source in ("v4l2", "host", "live")


@runtime_checkable
class Camera(Protocol):
    name: str
    kind: str

    def open(self) -> None:
        """Open (or re-open) the device; CameraUnavailable / CameraFormatError on failure."""

    def read(self, timeout_s: float) -> Frame | None:
        """Next frame, or None if none arrived within ``timeout_s`` (see module docstring)."""

    def close(self) -> None:
        """Release the device; idempotent."""

    def info(self) -> CameraInfo:
        """Negotiated format and timestamp source (requested values before the first open)."""

    @property
    def nominal_fps(self) -> float | None:
        """Frame rate the camera is expected to deliver (for the skew gate and watchdog)."""

    def reset_hardware(self) -> str:
        """Last-resort reset (USB reset for V4L2); returns what was done, RigError if impossible."""


@runtime_checkable
class FaultInjectable(Protocol):
    def inject(self, fault: Fault) -> None:
        """Activate a fault at runtime, thread-safe (see rig.capture.faults)."""


class TimeBase:
    """A shared origin for replayed "live" timestamps, so two replayed cameras share one clock.

    The first camera to ask fixes the anchor (``time.monotonic_ns()`` then); every later call
    returns the same value. Hardware cameras ignore it.
    """

    def __init__(self, clock: Callable[[], int] = time.monotonic_ns) -> None:
        self._clock = clock
        self._anchor: int | None = None
        self._lock = threading.Lock()

    def anchor_ns(self) -> int:
        with self._lock:
            if self._anchor is None:
                self._anchor = self._clock()
            return self._anchor
